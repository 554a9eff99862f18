"""The agent process: one agent, or a pool of agents sharing one Zenoh session (``--pool``).

Lockstep (ARCHITECTURE.md "Time"): publish ``x_i[k]``; wait for netem's close
marker of the state phase and exactly the packets it lists; report tokens and
measurements; wait for the estimate phase's marker; step to ``x_i[k+1]``.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

from agent.runner import AgentRunner, Packet
from formation import keys
from formation.codec import attachment, read_attachment
from formation.messages import (
    CoordinationState,
    EpochClose,
    LeaderEstimate,
    Measurement,
    Substitute,
    TokenReport,
)
from formation.realtime import ESTIMATE_DEADLINE, STATE_DEADLINE, fetch_clock, sleep_until
from formation.scenario import Scenario, StrategyName
from formation.service import Incoming, Service

log = logging.getLogger("agent")
_BAD = object()


@dataclass
class _Inbox:
    """What has arrived for one agent and not yet been used."""

    packets: dict[tuple[int, int], object] = field(default_factory=dict)  # (source, seq) → position
    closes: dict[tuple[str, int], EpochClose] = field(default_factory=dict)
    estimates: dict[int, object] = field(default_factory=dict)  # epoch → LeaderEstimate


class AgentNode:
    """Drives :class:`AgentRunner` instances from Zenoh traffic, one phase at a time."""

    def __init__(
        self,
        service: Service,
        scenario: Scenario,
        ids: list[int],
        strategy: StrategyName,
        seed: int,
    ) -> None:
        self.service, self.scenario = service, scenario
        self.run_id = service.run_id
        self.runners = {i: AgentRunner(scenario, i, strategy, seed) for i in ids}
        self.inbox = {i: _Inbox() for i in ids}
        self.phase = dict.fromkeys(ids, "state")  # waiting for the close of this phase
        self.done: set[int] = set()
        self.taken = dict.fromkeys(ids, -1)  # realtime: last epoch whose packets were taken
        self.deadline = {
            "packets": 0,
            "late_packets": 0,
            "estimates": 0,
            "late_estimates": 0,
            "overruns": 0,
        }
        for i in ids:
            service.subscribe(f"{keys.prefix(self.run_id)}/link/*/{i}/state")
            service.subscribe(keys.link_estimate(self.run_id, i))
            service.subscribe(f"{keys.prefix(self.run_id)}/close/{i}/*")
        service.watch_alive()

    def announce(self) -> None:
        for i in self.runners:
            self.service._keep.append(
                self.service.session.liveliness().declare_token(keys.alive(self.run_id, "agent", i))
            )

    # -- inbound --------------------------------------------------------------------------------
    @staticmethod
    def _receiver(key: str) -> int | None:
        """The agent a delivered key is for: ``close/<i>/...`` or ``link/<j>/<i>/...``."""
        parts = key.split("/")
        try:
            return int(parts[3]) if parts[2] == "close" else int(parts[4])
        except (IndexError, ValueError):
            return None

    def _route(self, msg: Incoming) -> None:
        parts = msg.key.split("/")
        kind = parts[-1]
        if parts[2] == "close":
            receiver = int(parts[3])
            close = self.service.malformed.decode(msg.key, msg.payload, EpochClose)
            if close is not None and receiver in self.inbox:
                self.inbox[receiver].closes[(close.phase, close.epoch)] = close
            return
        receiver = int(parts[4])
        if receiver not in self.inbox:
            return
        meta = read_attachment(msg.attachment)
        if kind == "state":
            state = self.service.malformed.decode(msg.key, msg.payload, CoordinationState)
            if meta is None:
                if state is None:
                    return
                meta = (state.epoch, state.seq, state.agent)
            sent_epoch, seq, source = meta
            if sent_epoch <= self.taken[receiver]:
                self.deadline["late_packets"] += 1  # realtime: arrived after its epoch's deadline
                return
            value: object = (
                _BAD if state is None else Packet(source, sent_epoch, tuple(state.position))
            )
            self.inbox[receiver].packets[(source, seq)] = value
        elif kind == "estimate":
            est = self.service.malformed.decode(msg.key, msg.payload, LeaderEstimate)
            if (
                est is not None
                and self.taken[receiver] >= 0
                and est.epoch < self.runners[receiver].epoch
            ):
                self.deadline["late_estimates"] += 1
            elif est is not None:
                self.inbox[receiver].estimates[est.epoch] = est
            elif meta is not None:
                self.inbox[receiver].estimates[meta[0]] = _BAD

    # -- phases -----------------------------------------------------------------------------------
    def _publish_state(self, runner: AgentRunner) -> None:
        key = keys.agent_state(self.run_id, runner.id)
        head = self.service.header(key, runner.epoch)
        subs = [Substitute(neighbour=j, value=v, fallback=f) for j, v, f in runner.substituted]
        msg = CoordinationState(**head, agent=runner.id, position=runner.position, substituted=subs)
        self.service.publish(key, msg, attachment(runner.epoch, head["seq"], runner.id))

    def _try_state_phase(self, i: int) -> bool:
        runner, box = self.runners[i], self.inbox[i]
        close = box.closes.get(("state", runner.epoch))
        if close is None or any((d.source, d.seq) not in box.packets for d in close.delivered):
            return False
        packets = []
        for d in close.delivered:
            value = box.packets.pop((d.source, d.seq))
            if isinstance(value, Packet):  # a malformed payload counts as lost
                packets.append(Packet(d.source, d.sent_epoch, value.position))
        del box.closes[("state", runner.epoch)]
        report = runner.receive(packets)
        key = keys.agent_report(self.run_id, i)
        head = self.service.header(key, runner.epoch)
        msg = TokenReport(
            **head, agent=i,
            measurements=[Measurement(neighbour=j, token=1 if t else 0, z=z) for j, t, z in report],
        )  # fmt: skip
        self.service.publish(key, msg, attachment(runner.epoch, head["seq"], i))
        self.phase[i] = "estimate"
        return True

    def _try_estimate_phase(self, i: int) -> bool:
        runner, box = self.runners[i], self.inbox[i]
        k = runner.epoch
        close = box.closes.get(("estimate", k))
        if close is None:
            return False
        on_time = [d for d in close.delivered if d.sent_epoch == k]
        if on_time and k not in box.estimates:
            return False
        est = box.estimates.pop(k, None)
        for old in [e for e in box.estimates if e < k]:
            del box.estimates[old]
        del box.closes[("estimate", k)]
        if isinstance(est, LeaderEstimate):
            runner.step(est.positions, est.v_ref)
        else:
            runner.step(None, None)
        self.phase[i] = "state"
        self._publish_state(runner)
        if runner.epoch >= self.scenario.epochs:
            self.done.add(i)
        return True

    def run(self, max_epochs: int) -> int:
        """Run every agent to ``max_epochs``; returns an exit code."""
        if not self.service.wait_started():
            return 1
        for runner in self.runners.values():
            self._publish_state(runner)
        while len(self.done) < len(self.runners) and not self.service.stopping.is_set():
            msg = self.service.next_incoming(0.2)
            if msg is None:
                if self.service.gone_for("netem", 0):
                    log.error("netem is gone; stopping")
                    return 2
                continue
            receiver = self._receiver(msg.key)
            self._route(msg)
            # Only the agent this message was for can have moved on.
            while receiver in self.runners and receiver not in self.done:
                step = (
                    self._try_state_phase
                    if self.phase[receiver] == "state"
                    else self._try_estimate_phase
                )
                if not step(receiver):
                    break
        return 0 if len(self.done) == len(self.runners) else 130

    # -- realtime ---------------------------------------------------------------------------------
    def _drain_until(self, t_ns: int) -> None:
        while True:
            left = (t_ns - time.time_ns()) / 1e9
            if left <= 0:
                return
            msg = self.service.next_incoming(min(left, 0.05))
            if msg is not None:
                self._route(msg)

    def run_realtime(self) -> int:
        """Fixed period; what has not arrived by a phase's deadline is lost (ARCHITECTURE.md "Time")."""
        if not self.service.wait_started():
            return 1
        clock = fetch_clock(self.service.session, self.run_id)
        for k in range(self.scenario.epochs):
            if self.service.stopping.is_set():
                return 130
            if time.time_ns() > clock.at(k, STATE_DEADLINE):
                self.deadline["overruns"] += 1
            sleep_until(clock.at(k))
            for runner in self.runners.values():
                self._publish_state(runner)
            self._drain_until(clock.at(k, STATE_DEADLINE))
            for i, runner in self.runners.items():
                box = self.inbox[i]
                packets = [
                    p for p in box.packets.values() if isinstance(p, Packet) and p.sent_epoch <= k
                ]
                self.deadline["packets"] += sum(p.sent_epoch == k for p in packets)
                box.packets.clear()
                self.taken[i] = k
                report = runner.receive(packets)
                key = keys.agent_report(self.run_id, i)
                head = self.service.header(key, k)
                msg = TokenReport(**head, agent=i, measurements=[
                    Measurement(neighbour=j, token=1 if t else 0, z=z) for j, t, z in report])  # fmt: skip
                self.service.publish(key, msg, attachment(k, head["seq"], i))
            self._drain_until(clock.at(k, ESTIMATE_DEADLINE))
            for i, runner in self.runners.items():
                est = self.inbox[i].estimates.pop(k, None)
                self.inbox[i].estimates.clear()
                if isinstance(est, LeaderEstimate):
                    self.deadline["estimates"] += 1
                    runner.step(est.positions, est.v_ref)
                else:
                    runner.step(None, None)
        sleep_until(clock.at(self.scenario.epochs))
        for runner in self.runners.values():
            self._publish_state(runner)
        self.done = set(self.runners)
        return 0
