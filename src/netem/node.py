"""The netem process: every message between services crosses it as a directed link.

Lockstep (ARCHITECTURE.md "Time"): for each packet netem asks the link's model
(keyed by seed, link and epoch, so any process gets the same verdict), forwards
the payload unparsed (epoch, seq and source ride in the attachment), and once
every live sender's epoch-``k`` packet into a receiver is handled it sends that
receiver an :class:`EpochClose` listing what was delivered. Delays are whole
epochs: a delayed packet is delivered with the close of a later epoch.
"""

from __future__ import annotations

import heapq
import json
import logging
import time
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Any, Literal

import zenoh
from pydantic import TypeAdapter, ValidationError

from formation import keys
from formation.codec import attachment, read_attachment
from formation.linkmodels import LinkModelSpec
from formation.messages import Decision, DecisionBatch, Delivered, EpochClose, LinkChange
from formation.realtime import Clock
from formation.scenario import LEADER_ENDPOINT, Scenario
from formation.service import Incoming, Service
from netem.models import LinkModel

log = logging.getLogger("netem")
LinkClass = Literal["formation", "report", "estimate"]
Phase = Literal["state", "report", "estimate"]
_PHASE_OF: dict[LinkClass, Phase] = {
    "formation": "state",
    "report": "report",
    "estimate": "estimate",
}
_SPECS: TypeAdapter[list[LinkModelSpec]] = TypeAdapter(list[LinkModelSpec])


@dataclass
class _Held:
    """A packet held for a later epoch (delay), forwarded with that epoch's close."""

    key: str
    payload: bytes
    source: int
    seq: int
    sent_epoch: int
    copies: int


@dataclass
class _Open:
    """An epoch of one phase into one receiver, not yet closed."""

    handled: set[int] = field(default_factory=set)
    delivered: list[Delivered] = field(default_factory=list)
    lost: list[int] = field(default_factory=list)


class NetemNode:
    def __init__(
        self,
        service: Service,
        scenario: Scenario,
        seed: int,
        wait_for_recorder: bool = True,
        passthrough: bool = False,
    ) -> None:
        self.service, self.scenario, self.seed = service, scenario, seed
        self.run_id = service.run_id
        self.wait_for_recorder = wait_for_recorder
        self.passthrough = (
            passthrough  # benchmark baseline: forward everything, decide and record nothing
        )
        self.lock = service.inline_lock  # the config queryable and the inline handler share it
        n = scenario.n
        self.agents = list(range(1, n + 1))
        self.models: dict[tuple[LinkClass, int, int], LinkModel] = {}
        self.in_links: dict[int, list[int]] = defaultdict(list)
        self.out_links: dict[int, list[int]] = defaultdict(list)
        for a, b in scenario.directed_links:
            a, b = int(a), int(b)
            self.models[("formation", a, b)] = LinkModel(
                scenario.formation_link_models(a, b), seed, a, b
            )
            self.out_links[a].append(b)
            self.in_links[b].append(a)
        for i in self.agents:
            self.models[("report", i, LEADER_ENDPOINT)] = LinkModel(
                scenario.control_link_models(i, "report"), seed, i, LEADER_ENDPOINT
            )
            self.models[("estimate", LEADER_ENDPOINT, i)] = LinkModel(
                scenario.control_link_models(i, "estimate"), seed, LEADER_ENDPOINT, i
            )
        self.open: dict[tuple[Phase, int, int], _Open] = {}  # (phase, receiver, epoch)
        self.held: dict[tuple[Phase, int, int], list[_Held]] = defaultdict(list)
        self.next_close: dict[tuple[Phase, int], int] = defaultdict(int)
        self.decisions: dict[tuple[Phase, int], list[Decision]] = defaultdict(list)
        self.closed_count: dict[tuple[Phase, int], int] = defaultdict(int)
        self.dead: set[int] = set()
        self.final_states: set[int] = set()
        self.estimates_done = 0
        self.epoch_seen = 0
        prefix = keys.prefix(self.run_id)
        for key in (
            f"{prefix}/agent/*/state",
            f"{prefix}/agent/*/report",
            keys.leader_estimate_out(self.run_id),
        ):
            service.subscribe(key)
        service.queryable(keys.netem_config(self.run_id), self._on_config)
        self.clock: Clock | None = None
        service.queryable(keys.clock(self.run_id), self._on_clock)
        service.watch_alive()

    # -- liveliness ---------------------------------------------------------------------------
    def _check_dead(self, grace_s: float = 3.0) -> None:
        """Agents whose liveliness token has been gone ``grace_s`` are no longer waited for."""
        for i in self.agents:
            if (
                i not in self.dead
                and i not in self.final_states
                and self.service.gone_for("agent", i, grace_s)
            ):
                with self.lock:
                    self._on_dead(i)

    def everyone_up(self) -> bool:
        need = [("agent", i) for i in self.agents] + [("leader", 0)]
        if self.wait_for_recorder:
            need.append(("recorder", 0))
        return all(self.service.is_alive(role, ident) for role, ident in need)

    # -- decisions ------------------------------------------------------------------------------
    def _decide(self, cls: LinkClass, src: int, dst: int, epoch: int, seq: int) -> Any:
        decision = self.models[(cls, src, dst)].decide(epoch)
        # model_construct: the values come from our own models, so the per-packet cost stays low.
        self.decisions[(_PHASE_OF[cls], epoch)].append(
            Decision.model_construct(
                source=src,
                target=dst,
                link_class=cls,
                epoch=epoch,
                seq=seq,
                verdict=decision.verdict,  # type: ignore[arg-type]  # one of Decision's verdicts
                delay_epochs=decision.delay_epochs,
                delay_ms=decision.delay_ms,
                model=decision.model,
                state=decision.state,
            )
        )
        return decision

    def _route_packet(self, phase: Phase, cls: LinkClass, src: int, dst: int, key: str, payload: bytes,
                      epoch: int, seq: int) -> None:  # fmt: skip
        box = self.open.setdefault((phase, dst, epoch), _Open())
        box.handled.add(src)
        d = self._decide(cls, src, dst, epoch, seq)
        if not d.delivered:
            box.lost.append(src)
        elif d.delay_epochs == 0:
            for _ in range(d.copies):
                self.service.put(key, payload, attachment(epoch, seq, src))
            box.delivered.append(
                Delivered.model_construct(source=src, seq=seq, sent_epoch=epoch, copies=d.copies)
            )
        else:
            box.lost.append(src)  # lost for this epoch; arrives with a later one
            self.held[(phase, dst, epoch + d.delay_epochs)].append(
                _Held(key, payload, src, seq, epoch, d.copies)
            )

    def _senders(self, phase: Phase, receiver: int) -> list[int]:
        if phase == "state":
            return self.in_links[receiver]
        if phase == "report":
            return self.agents
        return [LEADER_ENDPOINT]

    def _try_close(self, phase: Phase, receiver: int) -> None:
        while True:
            epoch = self.next_close[(phase, receiver)]
            box = self.open.get((phase, receiver, epoch))
            waiting = [s for s in self._senders(phase, receiver) if s not in self.dead]
            if box is None or any(s not in box.handled for s in waiting):
                if box is None and not waiting and epoch < self.scenario.epochs:
                    box = self.open.setdefault((phase, receiver, epoch), _Open())
                else:
                    return
            del self.open[(phase, receiver, epoch)]
            for h in self.held.pop((phase, receiver, epoch), []):
                for _ in range(h.copies):
                    self.service.put(h.key, h.payload, attachment(h.sent_epoch, h.seq, h.source))
                box.delivered.append(
                    Delivered.model_construct(
                        source=h.source, seq=h.seq, sent_epoch=h.sent_epoch, copies=h.copies
                    )
                )
            key = keys.close(self.run_id, receiver, phase)
            dead = sorted(s for s in self._senders(phase, receiver) if s in self.dead)
            msg = EpochClose(**self.service.header(key, epoch), receiver=receiver, phase=phase,
                             delivered=box.delivered, lost=sorted(box.lost), dead=dead)  # fmt: skip
            self.service.publish(key, msg)
            self.next_close[(phase, receiver)] = epoch + 1
            self.closed_count[(phase, epoch)] += 1
            receivers = len(self.agents) - len(self.dead) if phase != "report" else 1
            if self.closed_count[(phase, epoch)] >= receivers:
                self._publish_decisions(phase, epoch)

    def _publish_decisions(self, phase: Phase, epoch: int) -> None:
        batch = self.decisions.pop((phase, epoch), [])
        key = keys.netem_decision(self.run_id)
        self.service.publish(
            key, DecisionBatch(**self.service.header(key, epoch), phase=phase, decisions=batch)
        )

    # -- inbound ----------------------------------------------------------------------------------
    def handle(self, msg: Incoming) -> None:
        meta = read_attachment(msg.attachment)
        if meta is None:
            self.service.malformed.counts[msg.key] += 1
            return
        epoch, seq, source = meta
        parts = msg.key.split("/")
        kind = parts[-1]
        if self.passthrough and kind == "state" and parts[2] == "agent":
            for dst in self.out_links.get(source, ()):
                self.service.put(
                    keys.link_state(self.run_id, source, dst), msg.payload, msg.attachment
                )
            return
        if parts[2] == "agent":
            if int(parts[3]) != source or source not in self.agents:
                self.service.malformed.counts[msg.key] += 1
                return
            if kind == "state":
                self.epoch_seen = max(self.epoch_seen, epoch)
                if epoch >= self.scenario.epochs:
                    self.final_states.add(source)
                    return
                for dst in self.out_links[source]:
                    if dst in self.dead:
                        continue
                    self._route_packet("state", "formation", source, dst,
                                       keys.link_state(self.run_id, source, dst), msg.payload, epoch, seq)  # fmt: skip
                for dst in self.out_links[source]:
                    self._try_close("state", dst)
            elif kind == "report":
                self._route_packet("report", "report", source, LEADER_ENDPOINT,
                                   keys.link_report(self.run_id, source), msg.payload, epoch, seq)  # fmt: skip
                self._try_close("report", LEADER_ENDPOINT)
        elif kind == "estimate" and parts[2] == "leader":
            for i in self.agents:
                if i in self.dead:
                    continue
                self._route_packet("estimate", "estimate", LEADER_ENDPOINT, i,
                                   keys.link_estimate(self.run_id, i), msg.payload, epoch, seq)  # fmt: skip
                self._try_close("estimate", i)
            self.estimates_done = max(self.estimates_done, epoch + 1)

    def _on_dead(self, agent: int) -> None:
        if agent in self.dead or agent in self.final_states:
            return
        log.warning("agent %d is gone: its packets count as lost from now on", agent)
        self.dead.add(agent)
        for j in self.out_links[agent]:
            self._try_close("state", j)
        self._try_close("report", LEADER_ENDPOINT)

    def finished(self) -> bool:
        live = [i for i in self.agents if i not in self.dead]
        return self.estimates_done >= self.scenario.epochs and all(
            i in self.final_states for i in live
        )

    # -- run-time changes ----------------------------------------------------------------------------
    def _on_config(self, query: zenoh.Query) -> None:
        try:
            request = json.loads(query.payload.to_bytes()) if query.payload else {"op": "show"}
            with self.lock:
                answer = self._config(request)
            query.reply(query.key_expr, json.dumps(answer).encode())
        except Exception as exc:
            query.reply(query.key_expr, json.dumps({"ok": False, "error": str(exc)}).encode())

    def _config(self, request: dict[str, Any]) -> dict[str, Any]:
        op = request.get("op", "show")
        if op == "show":
            return {"ok": True, "epoch": self.epoch_seen, "links": [
                {"link": f"{s}->{d}", "class": c, "models": [m.model_dump(by_alias=True) for m in lm.specs]}
                for (c, s, d), lm in sorted(self.models.items())
            ]}  # fmt: skip
        if op != "set":
            return {"ok": False, "error": f"op {op!r}: expected show or set"}
        link = str(request.get("link", ""))
        try:
            src_text, dst_text = link.split("->")
            src, dst = int(src_text), int(dst_text)
        except ValueError:
            return {
                "ok": False,
                "error": f"link {link!r}: expected SRC->DST, e.g. 1->2 (0 is the leader)",
            }
        cls: LinkClass = (
            "report"
            if dst == LEADER_ENDPOINT
            else "estimate"
            if src == LEADER_ENDPOINT
            else "formation"
        )
        if (cls, src, dst) not in self.models:
            return {"ok": False, "error": f"link {link!r}: no such link in the scenario"}
        try:
            specs = _SPECS.validate_python(request.get("models", []))
        except ValidationError as exc:
            err = exc.errors()[0]
            where = ".".join(str(p) for p in err["loc"])
            return {"ok": False, "error": f"models.{where} = {err.get('input')!r}; {err['msg']}"}
        from_epoch = self.epoch_seen + 1
        self.models[(cls, src, dst)].replace(specs, from_epoch)
        key = keys.netem_change(self.run_id)
        change = LinkChange(**self.service.header(key, from_epoch), source=src, target=dst, link_class=cls,
                            models=[s.model_dump(by_alias=True) for s in specs], from_epoch=from_epoch)  # fmt: skip
        self.service.publish(key, change)
        return {"ok": True, "link": link, "class": cls, "from_epoch": from_epoch}

    # -- realtime --------------------------------------------------------------------------------------
    def _on_clock(self, query: zenoh.Query) -> None:
        if self.clock is None:
            query.reply_err(b"not started")
        else:
            query.reply(query.key_expr, self.clock.to_json())

    def _forward_realtime(self, cls: LinkClass, src: int, dst: int, key: str, msg: Incoming,
                          epoch: int, seq: int, due: list[tuple[int, int, str, bytes, bytes]]) -> None:  # fmt: skip
        assert self.clock is not None
        now = time.time_ns()
        d = self.models[(cls, src, dst)].decide(epoch, time_s=(now - self.clock.t0_ns) / 1e9)
        self.decisions[(_PHASE_OF[cls], epoch)].append(
            Decision(
                source=src,
                target=dst,
                link_class=cls,
                epoch=epoch,
                seq=seq,
                verdict=d.verdict,
                delay_ms=d.delay_ms,
                model=d.model,
                state=d.state,
            )
        )
        if not d.delivered:
            return
        att = attachment(epoch, seq, src)
        if d.delay_ms <= 0:
            for _ in range(d.copies):
                self.service.put(key, msg.payload, att)
        else:
            for _ in range(d.copies):
                heapq.heappush(due, (now + int(d.delay_ms * 1e6), len(due), key, msg.payload, att))

    def _handle_realtime(
        self, msg: Incoming, due: list[tuple[int, int, str, bytes, bytes]]
    ) -> None:
        meta = read_attachment(msg.attachment)
        if meta is None:
            self.service.malformed.counts[msg.key] += 1
            return
        epoch, seq, source = meta
        parts = msg.key.split("/")
        if parts[2] == "agent":
            if int(parts[3]) != source or source not in self.agents:
                self.service.malformed.counts[msg.key] += 1
                return
            if parts[-1] == "state":
                self.epoch_seen = max(self.epoch_seen, epoch)
                if epoch >= self.scenario.epochs:
                    self.final_states.add(source)
                    return
                for dst in self.out_links[source]:
                    self._forward_realtime("formation", source, dst, keys.link_state(self.run_id, source, dst),
                                           msg, epoch, seq, due)  # fmt: skip
            elif parts[-1] == "report":
                self._forward_realtime("report", source, LEADER_ENDPOINT, keys.link_report(self.run_id, source),
                                       msg, epoch, seq, due)  # fmt: skip
        elif parts[2] == "leader" and parts[-1] == "estimate":
            for i in self.agents:
                self._forward_realtime("estimate", LEADER_ENDPOINT, i, keys.link_estimate(self.run_id, i),
                                       msg, epoch, seq, due)  # fmt: skip
            self.estimates_done = max(self.estimates_done, epoch + 1)

    def run_realtime(self, period_s: float) -> int:
        """Forward each packet as it comes (after its model's delay in ms); no epoch closes."""
        while not self.everyone_up():
            if self.service.stopping.wait(0.02):
                return 130
        self.clock = Clock(time.time_ns() + int(0.3e9), int(period_s * 1e9))
        self.service.declare_start()
        due: list[tuple[int, int, str, bytes, bytes]] = []
        next_flush = self.clock.at(1)
        while not (self.finished() and not due) and not self.service.stopping.is_set():
            now = time.time_ns()
            while due and due[0][0] <= now:
                _, _, key, payload, att = heapq.heappop(due)
                self.service.put(key, payload, att)
            if now >= next_flush:
                for phase, epoch in sorted(self.decisions):
                    self._publish_decisions(phase, epoch)
                next_flush += self.clock.period_ns
            wait = 0.05 if not due else max(0.0, min(0.05, (due[0][0] - now) / 1e9))
            msg = self.service.next_incoming(wait)
            self._check_dead()
            if msg is not None:
                with self.lock:
                    self._handle_realtime(msg, due)
        for phase, epoch in sorted(self.decisions):
            self._publish_decisions(phase, epoch)
        return 0 if self.finished() else 130

    # -- main loop -------------------------------------------------------------------------------------
    def run(self) -> int:
        self.service.inline = self.handle  # lockstep: handled on Zenoh's thread, no queue hand-off
        while not self.everyone_up():
            if self.service.stopping.wait(0.02):
                return 130
        self.service.declare_start()
        while not self.finished() and not self.service.stopping.is_set():
            msg = self.service.next_incoming(0.2)
            self._check_dead()
            if msg is None:
                if (
                    self.service.gone_for("leader", 0)
                    and self.estimates_done < self.scenario.epochs
                ):
                    log.error("the leader is gone; stopping")
                    return 2
                continue
            with self.lock:
                self.handle(msg)
        return 0 if self.finished() else 130
