"""The netem process: every message between services crosses it as a directed link.

This is the transport shell: the bus's subscriptions, the ``clock``, ``netem/final``,
``netem/rejoin`` and ``netem/pool`` queryables (``netem/config`` is :mod:`netem.link_config`'s, the
publishers :mod:`netem.outbox`'s), liveliness and what each wake-up of its one
loop (:mod:`netem.proxy.loop`) does in lockstep. The logic is elsewhere: lockstep in
:mod:`netem.proxy.lockstep` (pure), realtime
forwarding in :mod:`netem.proxy.realtime`.
"""

from __future__ import annotations

import logging
import threading
import time
from functools import partial
from typing import Any

import orjson

from formation import keys
from formation.codec import read_attachment
from formation.keys import LEADER_ENDPOINT
from formation.scenario import Scenario
from netem.bundle_parts import read_bundle
from netem.last_state import state_of
from netem.link_config import LinkConfig
from netem.outbox import ZenohOutbox
from netem.proxy.bundle_pass import BundlePass
from netem.proxy.lockstep import LockstepCore
from netem.proxy.loop import Wakeups, run_loop
from netem.proxy.progress import Progress
from netem.proxy.realtime import RealtimeForwarder
from netem.proxy.records import Ledger
from netem.proxy.routes import Links, Routes, link_key
from shell import Incoming, Query, Sample, Service, TimePolicy, settle_heap

log = logging.getLogger("netem")
LOCKSTEP_WAKE_S = (
    0.2  # lockstep: the loop's longest sleep; closed epochs' records wait at most this
)
REJOIN_AHEAD = 2  # realtime: epochs between the one under way and an unscheduled restart's first
FINAL_WAIT_S = 0.5  # how long a last-messages query waits for what may still be on its way


class NetemNode:
    """netem's shell: the bus in and out, queryables and liveliness; the logic is the cores'."""

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
        self.passthrough = passthrough  # the benchmarks' baseline: forward all, decide nothing
        self.lock = service.inline_lock  # the config queryable and the sample handler share it
        self.epochs = scenario.epochs
        self.links = Links(scenario, seed)
        self.agents = self.links.agents
        self._last_seen = threading.Condition()  # notified on a final state or a finished epoch
        self.progress = Progress(self.agents, self.epochs, self._notify_last_seen)
        self.ledger = Ledger()
        self.outbox = ZenohOutbox(service)
        self.outbox.declare(self.agents)
        self.lockstep = LockstepCore(
            self.links, self.epochs, self.progress, self.ledger, self.outbox
        )
        self.bundles = BundlePass(self.lockstep)
        self.routes = Routes(self.agents)
        self.realtime = RealtimeForwarder(
            service,
            self.links,
            self.routes,
            self.progress,
            self.ledger,
            self.outbox.records,
            self.outbox.deliver,
            self.lock,
        )
        self.running = False  # lockstep: samples are handled on the bus's thread once True
        self.timing: TimePolicy | None = None  # set by run
        self._estimates = keys.leader_estimates(self.run_id)
        for key in (
            keys.agent_state(self.run_id, "*"),
            keys.agent_report(self.run_id, "*"),
            keys.leader_estimate_for(self.run_id, "*"),
            self._estimates,
            keys.pool_bundle(self.run_id, "*", "report"),
            keys.pool_states(self.run_id, "*"),
        ):
            service.subscribe(key, self._on_sample)
        config = LinkConfig(service, self.links, self.progress, self.lockstep, self.lock)
        service.queryable(keys.netem_config(self.run_id), config.on_query)
        service.queryable(keys.clock(self.run_id), self._on_clock)
        service.queryable(keys.netem_final(self.run_id), self._on_final)
        service.queryable(keys.netem_rejoin(self.run_id), self._on_rejoin)
        service.queryable(keys.netem_pool(self.run_id), self._on_pool)
        self._unsure = set(self.agents)  # agents whose token was missing when last looked at
        service.watch_alive(self._on_alive)

    @property
    def final_states(self) -> set[int]:
        return self.progress.final_states

    @property
    def estimates_done(self) -> int:
        return self.progress.estimates_done

    @property
    def dead(self) -> set[int]:
        return self.lockstep.dead

    def finished(self) -> bool:
        return self.lockstep.finished()

    def sent_counts(self) -> dict[str, int]:
        """Delivered packets per link, named by the link's key (for the final status)."""
        return {link_key(self.run_id, link): n for link, n in self.lockstep.forwarded().items()}

    # -- liveliness ---------------------------------------------------------------------------
    def _on_alive(self, role: str, ident: str, alive: bool) -> None:
        if role == "agent" and not alive and ident.isdigit():
            self._unsure.add(int(ident))  # looked at by the next _check_dead

    def _check_dead(self, grace_s: float = 3.0, leader: bool = True) -> None:
        """Senders whose liveliness token has been gone ``grace_s`` are no longer waited for
        (the leader too: agents fall back on lost estimates until it comes back). Only the
        agents whose token went missing since they were last seen alive are looked at."""
        for i in sorted(self._unsure.copy()):
            self._unsure.discard(i)  # before looking: a token lost after is added again
            if self.service.is_alive("agent", i):
                self.service.gone_for("agent", i, grace_s)  # forgets when it went missing
                continue
            self._unsure.add(i)
            if (
                not self.lockstep.is_down(i)
                and i not in self.final_states
                and not self._away(i)  # out by the scenario's events: expected
                and self.service.gone_for("agent", i, grace_s)
            ):
                with self.lock:
                    self.on_dead(i)
        if (
            leader
            and not self.lockstep.is_down(LEADER_ENDPOINT)
            and self.estimates_done < self.epochs
            and self.service.gone_for("leader", 0, grace_s)
        ):
            with self.lock:
                self.on_dead(LEADER_ENDPOINT)

    def _away(self, agent: int) -> bool:
        """Whether ``agent`` is out of the team by the scenario's events now: in lockstep by
        the epochs netem closed, in realtime by the clock."""
        clock = self.realtime.clock
        if self.scenario.runtime.mode != "realtime" or clock is None:
            return agent in self.lockstep.away
        return not self.realtime.takes_part(agent, clock.epoch_of(time.time_ns()))

    def on_dead(self, sender: int) -> None:
        """``sender`` is down: no longer waited for (call under :attr:`lock`)."""
        self.lockstep.sender_died(sender)
        self.team_changed(f"lost {_sender_name(sender)}")

    def team_changed(self, event: str, epoch: int | None = None) -> None:
        """A ``running`` status naming who takes part from which epoch (recorded, and read
        by the launcher's live view): issue 20, who was in the team at each epoch.

        ``epoch``: a scenario event's own epoch (else the newest epoch netem has seen);
        ``team`` the agents taking part now, ``away`` those out by the scenario's events.
        """
        ls = self.lockstep
        down = sorted(i for i in ls.dead if ls.is_down(i))
        team = {
            "event": event,
            "epoch": self.progress.epoch_seen if epoch is None else epoch,
            "team": [i for i in self.agents if i not in ls.away and i not in down],
            "away": sorted(ls.away),
            "down": down,
            "back": {str(i): k for i, k in sorted(ls.revive.items())},
        }
        self.service.status("running", self.estimates_done, orjson.dumps(team).decode())

    def _announce_applied(self) -> None:
        """A status for each scenario event the lockstep core has applied since the last call:
        ``leave``/``crash`` at the agent's last state, ``join``/``restart`` at its rejoin."""
        applied, self.lockstep.applied = self.lockstep.applied, []
        for action, agent, epoch in applied:
            self.team_changed(f"{action} agent {agent}", epoch)

    def everyone_up(self) -> bool:
        # An agent that joins later (a scenario event) is not waited for at the start.
        need = [("agent", i) for i in self.agents if i not in self.lockstep.away]
        need.append(("leader", 0))
        if self.wait_for_recorder:
            need.append(("recorder", 0))
        return all(self.service.is_alive(role, ident) for role, ident in need)

    def _notify_last_seen(self) -> None:
        with self._last_seen:
            self._last_seen.notify_all()

    # -- inbound ----------------------------------------------------------------------------------
    def _on_sample(self, sample: Sample) -> None:
        """Every inbound packet: handled at once on Zenoh's thread in lockstep, else queued,
        stamped with its arrival (netem counts only its own late forwards in realtime)."""
        att = sample.attachment
        if not self.running:
            raw = None if att is None else att.to_bytes()
            msg = Incoming(str(sample.key_expr), sample.payload.to_bytes(), raw, time.time_ns())
            self.service.inbox.put(msg)
            return
        key = str(sample.key_expr)
        self.service.handle_inline(key, self.handle_packet, key, sample.payload, att)

    def handle(self, msg: Incoming) -> None:
        """A queued packet (one that came before the start)."""
        self.handle_packet(msg.key, msg.payload, msg.attachment)

    def handle_packet(self, key: str, payload: Any, att: Any) -> None:
        """A packet on ``key`` with its codec attachment (bytes or a sample's ``ZBytes``)."""
        route = self.routes.of(key)
        if route is None and (key == self._estimates or "/agent/pool/" in key):
            self.handle_bundle(key, payload)
            return
        raw = att if att is None or isinstance(att, bytes) else att.to_bytes()
        meta = read_attachment(raw)
        if meta is None or route is None or meta[2] != route[1]:
            self.service.malformed.counts[key] += 1
            return
        epoch, seq, source = meta
        if self.passthrough and route[0] == "state":
            for dst in self.links.out_links[source]:
                self.service.put(link_key(self.run_id, ("formation", source, dst)), payload, att)
            return
        self.lockstep.packet(route, epoch, seq, payload)
        if self.lockstep.applied:
            self._announce_applied()

    def handle_bundle(self, key: str, payload: Any) -> None:
        """A :class:`~formation.messages.Bundle` on ``key`` (the leader's estimates, or a
        declared pool's states or reports): each part handled as if it came on its agent's own key. A
        bundle of another phase, or a part for an agent the key's sender does not hold, is
        counted on ``key`` and skipped."""
        raw = payload if isinstance(payload, bytes) else payload.to_bytes()
        read = read_bundle(self.service.malformed, key, raw)
        if read is None:
            return
        bundle, payloads = read
        holds = self._holder(key, bundle.phase)
        if holds is None:
            self.service.malformed.counts[key] += 1
            return
        parts = bundle.parts
        agents = [part.agent for part in parts]
        if not holds.issuperset(agents):
            kept = [i for i, a in enumerate(agents) if a in holds]
            self.service.malformed.counts[key] += len(agents) - len(kept)
            parts, payloads = [parts[i] for i in kept], [payloads[i] for i in kept]
            agents = [part.agent for part in parts]
        self.bundles.bundle(bundle.phase, bundle.epoch, agents, [p.seq for p in parts], payloads)
        if self.lockstep.applied:
            self._announce_applied()

    def _holder(self, key: str, phase: str) -> frozenset[int] | None:
        """Which agents' parts a bundle of ``phase`` on ``key`` may carry: the leader's
        estimates any agent's, a pool's states and reports its own agents'; None: no bundle of
        ``phase`` belongs on ``key``."""
        if key == self._estimates:
            return self.routes.agents if phase == "estimate" else None
        parsed = keys.parse(key)
        if not (
            (parsed.kind == "pool_bundle" and parsed.args[1] == phase == "report")
            or (parsed.kind == "pool_states" and phase == "state")
        ):
            return None
        pool = int(parsed.args[0]) if parsed.args[0].isdigit() else -1  # -1: no pool's
        return self.outbox.pools.get(pool, frozenset())

    def _on_final(self, query: Query) -> None:
        """What netem still lacks of a sender's last messages: ``{"agents": [ids]}`` asks for
        those agents' final states, ``{"estimates": true}`` for the leader's last epoch.

        A sender asks before it closes its session and republishes what is missing: a
        state published just before a close was seen lost under load, in about 1 of 70
        realtime runs. Samples and queries come on different threads, so netem first
        waits a moment for what may still be on its way.
        """
        try:
            ask = orjson.loads(query.payload.to_bytes()) if query.payload else {}
            ids = [int(i) for i in ask.get("agents", [])]
            estimates = bool(ask.get("estimates", False))
        except (orjson.JSONDecodeError, AttributeError, TypeError, ValueError):
            self.service.malformed.counts[str(query.key_expr)] += 1
            query.reply_err(b'expected {"agents": [ids]} or {"estimates": true}')
            return

        def missing() -> list[int]:
            return [i for i in ids if i not in self.final_states]

        with self._last_seen:
            self._last_seen.wait_for(
                lambda: not missing() and (not estimates or self.estimates_done >= self.epochs),
                timeout=FINAL_WAIT_S,
            )
        answer = {"missing": missing(), "estimates_done": self.estimates_done}
        query.reply(query.key_expr, orjson.dumps(answer))

    def _on_rejoin(self, query: Query) -> None:
        """A restarted sender's question: ``{"agents": [ids]}`` or ``{"leader": true}``.

        The answer gives, per sender, the epoch it takes part from and, for an agent, the
        last state netem handled from it (``{"epoch": c, "position": [...]}``, or None):
        netem sees every state in lockstep and is always there, unlike the recorder, so
        it is where a body's true state is kept.
        """
        try:
            ask = orjson.loads(query.payload.to_bytes()) if query.payload else {}
            ids = [int(i) for i in ask.get("agents", [])]
            leader = bool(ask.get("leader", False))
            if any(i not in self.agents for i in ids):
                raise ValueError("unknown agent")
        except (orjson.JSONDecodeError, AttributeError, TypeError, ValueError):
            self.service.malformed.counts[str(query.key_expr)] += 1
            query.reply_err(b'expected {"agents": [ids]} or {"leader": true}')
            return
        if self.scenario.runtime.mode == "realtime":
            if leader:  # the leader is not restarted in realtime
                query.reply_err(b"realtime: the leader cannot rejoin a running run")
            elif not self._clock_set():
                query.reply(query.key_expr, orjson.dumps({"wait": True}))  # it asks again
            else:
                query.reply(query.key_expr, orjson.dumps(self._realtime_rejoin(ids)))
            return
        if not self._planned_ready(ids):
            query.reply(query.key_expr, orjson.dumps({"wait": True}))  # it asks again
            return
        answer: dict[str, Any] = {"agents": {}}
        for i in ids:
            self.service.seen_now("agent", i)
        if leader:
            self.service.seen_now("leader", 0)
        with self.lock:
            unplanned = [i for i in ids if self.lockstep.planned_start(i) is None]
            for i in ids:
                epoch = self.lockstep.rejoin(i)
                last = self.lockstep.state_of(i)
                answer["agents"][str(i)] = {"from_epoch": epoch, "state": state_of(last)}
            if leader:
                answer["leader"] = {"from_epoch": self.lockstep.rejoin(LEADER_ENDPOINT)}
            self._announce_applied()  # a scheduled join or restart: named by the scenario
            names = [f"agent {i}" for i in unplanned] + (["the leader"] if leader else [])
            if names:
                self.team_changed(f"back {', '.join(names)}")
        query.reply(query.key_expr, orjson.dumps(answer))

    def _on_pool(self, query: Query) -> None:
        """A pool process declares its agents, ``{"pool": p, "agents": [ids]}`` (``p`` its
        first agent): in lockstep their deliveries then come batched on
        ``inbox/pool/<p>/<phase>`` (answer ``{"batched": true}``); realtime keeps each on its
        receiver's key (``false``)."""
        try:
            ask = orjson.loads(query.payload.to_bytes()) if query.payload else {}
            pool, ids = int(ask["pool"]), [int(i) for i in ask["agents"]]
            if not ids or pool != ids[0] or any(i not in self.agents for i in ids):
                raise ValueError("unknown agent")
            taken = self.outbox.pool_of
            if any(taken.get(i, pool) != pool for i in ids):
                raise ValueError("an agent of another pool")
        except (orjson.JSONDecodeError, AttributeError, KeyError, TypeError, ValueError):
            self.service.malformed.counts[str(query.key_expr)] += 1
            query.reply_err(b'expected {"pool": first id, "agents": [ids]}, ids of no other pool')
            return
        batched = self.scenario.runtime.mode != "realtime"
        if batched:
            with self.lock:
                self.outbox.declare_pool(pool, ids)
        query.reply(query.key_expr, orjson.dumps({"batched": batched}))

    def _clock_set(self, wait_s: float = 2.0) -> bool:
        """Realtime: whether the run's clock is set (the run began), waiting up to ``wait_s``."""
        end = time.monotonic() + wait_s
        while self.realtime.clock is None and time.monotonic() < end:
            time.sleep(0.05)
        return self.realtime.clock is not None

    def _realtime_rejoin(self, ids: list[int]) -> dict[str, Any]:
        """Realtime: the epoch each agent takes part from, by the run's clock, and the last
        state netem forwarded from it. A scheduled join or restart starts at its epoch; any
        other restart :data:`REJOIN_AHEAD` epochs after the one under way (its state for that
        one would be late); an agent whose part is over, at the end."""
        clock = self.realtime.clock
        assert clock is not None  # set when the run began, before any process could restart
        now = clock.epoch_of(time.time_ns())
        team = self.scenario.membership
        answer: dict[str, Any] = {"agents": {}}
        for i in ids:
            k = max(now, 0)  # before the clock's first epoch: as at it
            if k <= self.epochs and team.present[k, i - 1]:
                epoch = k if now < 0 else now + REJOIN_AHEAD
            else:
                ahead = [first for first, _ in team.incarnations(i) if first > k]
                epoch = ahead[0] if ahead else self.epochs
            last = self.realtime.last_state.get(i)
            answer["agents"][str(i)] = {
                "from_epoch": min(epoch, self.epochs),
                "state": state_of(last),
            }
        return answer

    def _planned_ready(self, ids: list[int], wait_s: float = 2.0) -> bool:
        """Whether agents with a scheduled join or restart at ``r`` may start now: their last
        part is over and the run has reached epoch ``r − 1`` (so their ``x[r]`` comes in step
        with the others'); waits up to ``wait_s`` for that."""
        ls = self.lockstep

        def ready() -> bool:
            for i in ids:
                r = ls.planned_start(i)
                if r is not None and not (
                    (i in ls.away or i in ls.rejoined) and self.estimates_done >= r - 1
                ):
                    return False
            return True

        with self._last_seen:
            return self._last_seen.wait_for(ready, timeout=wait_s)

    # -- realtime --------------------------------------------------------------------------------------
    def _on_clock(self, query: Query) -> None:
        # the policy's clock: set before the start token goes out, so it is there once asked
        clock = None if self.timing is None else self.timing.clock
        if clock is None:
            query.reply_err(b"not started")
        else:
            query.reply(query.key_expr, clock.to_json())

    # -- the loop ----------------------------------------------------------------------------------
    def run(self, timing: TimePolicy) -> int:
        """Carry every link of the run under ``timing`` until each sender's last message is in
        (0) or until stopped (130). Lockstep: packets are handled on the bus's thread, and
        each wake-up of this one flushes closed epochs' records; realtime: every packet is
        forwarded after its model's delay in ms, by this thread, and no epoch closes."""
        self.timing = timing
        realtime = timing.realtime
        wakeups: Wakeups = self.realtime if realtime else LockstepWakeups(self)
        # realtime: no leader restart (issue 20 covers lockstep)
        check_dead = partial(self._check_dead, leader=not realtime)
        return run_loop(self.service, timing, wakeups, self.everyone_up, check_dead, self.finished)

    def flush_all(self) -> None:
        """Publish the records of every epoch closed (:meth:`LockstepCore.flush`), and any
        pool's deliveries still kept."""
        with self.lock:
            self.lockstep.flush()
            self.outbox.flush_pools()


class LockstepWakeups:
    """Lockstep: packets are handled on the bus's thread as they come (no queue hand-off);
    the loop's thread wakes every :data:`LOCKSTEP_WAKE_S` to flush closed epochs' records and
    handle what came before the start."""

    def __init__(self, node: NetemNode) -> None:
        self.node = node

    def open(self) -> None:
        node = self.node
        with node.lock:  # handled on the bus's thread from now on
            node.running = True

    def begin(self, timing: TimePolicy) -> None:
        settle_heap()
        timing.begin(self.node.service)

    def idle(self) -> bool:
        return True

    def tick(self) -> float:
        return LOCKSTEP_WAKE_S

    def wake(self, msg: Incoming | None) -> None:
        node = self.node
        node.flush_all()  # closed epochs' records wait at most this long
        if msg is not None:
            with node.lock:
                node.handle(msg)

    def end(self) -> None:
        self.node.flush_all()


def _sender_name(sender: int) -> str:
    return "the leader" if sender == LEADER_ENDPOINT else f"agent {sender}"
