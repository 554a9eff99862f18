"""The netem process: every message between services crosses it as a directed link.

Lockstep (ARCHITECTURE.md "Time"): for each packet netem asks the link's model
(keyed by seed, link and epoch, so any process gets the same verdict). Once every
live sender's epoch-``k`` packet into a receiver is handled, it sends that receiver
one :class:`Delivery` with the payloads it passed, unparsed: the delivery is also
the epoch's close. Delays are whole epochs: a delayed packet goes out with a later
epoch's delivery. One message per receiver and phase, instead of one per link and a
close, is what lets a pool of hundreds of agents keep up.

Realtime: each packet is forwarded on its link's key as it comes, after its delay.
"""

from __future__ import annotations

import heapq
import json
import logging
import threading
import time
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from typing import Any, Literal

import orjson
import zenoh
from pydantic import TypeAdapter, ValidationError

from formation import keys
from formation.codec import read_attachment
from formation.linkmodels import LinkModelSpec
from formation.messages import LinkChange
from formation.realtime import Clock
from formation.scenario import LEADER_ENDPOINT, Scenario
from formation.service import Incoming, Service, settle_heap
from netem.clean import CleanEpochs, Stream
from netem.models import LinkModel
from netem.records import Record, decision_batch, decision_batch_of, delivery, packet_json

log = logging.getLogger("netem")
LinkClass = Literal["formation", "report", "estimate"]
Phase = Literal["state", "report", "estimate"]
_PHASE_OF: dict[LinkClass, Phase] = {
    "formation": "state",
    "report": "report",
    "estimate": "estimate",
}
_Due = tuple[
    int, int, zenoh.Publisher, bytes, "bytes | None"
]  # (due ns, tie, link, payload, attachment)
_Route = tuple[str, int, int]
# Clean epochs' records go out together: one batch per this many epochs' records (and at
# least every loop wake-up of the main thread, 0.2 s), instead of one per epoch.
_FLUSH_CHUNKS = 64  # epochs
FINAL_WAIT_S = 0.5  # how long a last-messages query waits for what may still be on its way
_SPECS: TypeAdapter[list[LinkModelSpec]] = TypeAdapter(list[LinkModelSpec])
_DELIVERED: list[bytes] = []  # marks a receiver whose delivery of a clean epoch went out


@dataclass
class _Held:
    """A packet held for a later epoch (delay), delivered with that epoch's packets."""

    link: tuple[LinkClass, int, int]
    copies: int
    packet: bytes  # encoded by packet_json, with its sent epoch


@dataclass
class _Open:
    """An epoch of one phase into one receiver, not yet closed."""

    handled: set[int] = field(default_factory=set)
    packets: list[bytes] = field(default_factory=list)  # each encoded by packet_json
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
        self.lock = service.inline_lock  # the config queryable and the sample handler share it
        n = scenario.n
        self.agents = list(range(1, n + 1))
        self.epochs = scenario.epochs
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
        self.decisions: dict[tuple[Phase, int], list[Record]] = defaultdict(list)
        self.closed_count: dict[tuple[Phase, int], int] = defaultdict(int)
        self.forwarded: Counter[tuple[LinkClass, int, int]] = Counter()
        self._links: dict[tuple[LinkClass, int, int], tuple[zenoh.Publisher, LinkModel]] = {}
        self._routes: dict[str, _Route | None] = {}  # inbound key → (kind, source, target)
        self._inboxes: dict[tuple[Phase, int], tuple[str, zenoh.Publisher]] = {}
        self._estimates_seen: Counter[int] = Counter()  # epoch → agents' estimates handled
        self.clean: dict[Phase, CleanEpochs] = {}  # lockstep, set up by run()
        self.dead: set[int] = set()
        self.final_states: set[int] = set()
        self.estimates_done = 0
        self._last_seen = threading.Condition()  # notified on a final state or a finished epoch
        self.epoch_seen = 0
        self.running = False  # lockstep: samples are handled on Zenoh's thread once True
        prefix = keys.prefix(self.run_id)
        for key in (
            f"{prefix}/agent/*/state",
            f"{prefix}/agent/*/report",
            keys.leader_estimate_for(self.run_id, "*"),
        ):
            service.subscribe(key, self._on_sample)
        service.queryable(keys.netem_config(self.run_id), self._on_config)
        self.clock: Clock | None = None
        service.queryable(keys.clock(self.run_id), self._on_clock)
        service.queryable(keys.netem_final(self.run_id), self._on_final)
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

    # -- links --------------------------------------------------------------------------------
    def _link_key(self, cls: LinkClass, src: int, dst: int) -> str:
        """The key a link's packets are forwarded on in realtime (and named by in lockstep)."""
        if cls == "formation":
            return keys.link_state(self.run_id, src, dst)
        if cls == "report":
            return keys.link_report(self.run_id, src)
        return keys.link_estimate(self.run_id, dst)

    def _link(self, cls: LinkClass, src: int, dst: int) -> tuple[zenoh.Publisher, LinkModel]:
        """Realtime: the publisher of a link's forwarded packets and its model, looked up once."""
        got = self._links.get((cls, src, dst))
        if got is None:
            got = self._links[(cls, src, dst)] = (
                self.service.publisher(self._link_key(cls, src, dst)),
                self.models[(cls, src, dst)],
            )
        return got

    def sent_counts(self) -> dict[str, int]:
        """Delivered packets per link, named by the link's key (for the final status)."""
        total = Counter(self.forwarded)
        for ce in self.clean.values():
            for stream in ce.streams.values():  # each finished epoch had one packet per stream
                for link in stream.links:
                    total[link] += len(ce.done)  # type: ignore[index]
        return {self._link_key(*link): count for link, count in total.items()}

    def _deliver(self, phase: Phase, receiver: int, epoch: int, packets: list[bytes],
                 lost: list[int], dead: list[int]) -> None:  # fmt: skip
        out = self._inboxes.get((phase, receiver))
        if out is None:
            key = keys.inbox(self.run_id, receiver, phase)
            out = self._inboxes[(phase, receiver)] = (key, self.service.publisher(key))
        key, pub = out
        pub.put(delivery(self.service.header(key, epoch), receiver, phase, packets, lost, dead))
        self.service.sent[key] += 1

    def _route_packet(self, phase: Phase, cls: LinkClass, src: int, dst: int, payload: Any,
                      epoch: int, seq: int) -> _Open:  # fmt: skip
        """Decide and record one packet, and put it in its receiver's open epoch (returned)."""
        key = (phase, dst, epoch)
        box = self.open.get(key)
        if box is None:
            box = self.open[key] = _Open()
        box.handled.add(src)
        d = self.models[(cls, src, dst)].decide(epoch)
        self.decisions[(phase, epoch)].append((src, dst, cls, epoch, seq, d))
        if not d.delivered:
            box.lost.append(src)
        elif d.delay_epochs == 0:
            box.packets.append(packet_json(src, seq, epoch, d.copies, payload))
            self.forwarded[(cls, src, dst)] += d.copies
        else:
            box.lost.append(src)  # lost for this epoch; arrives with a later one
            self.held[(phase, dst, epoch + d.delay_epochs)].append(
                _Held((cls, src, dst), d.copies, packet_json(src, seq, epoch, d.copies, payload))
            )
        return box

    # -- clean epochs: every link of the phase passes (netem.clean) --------------------------
    def _setup_clean(self) -> None:
        def stream(links: list[tuple[LinkClass, int, int]]) -> Stream:
            models = tuple(self.models[link] for link in links)
            return Stream(tuple(links), tuple(dst for _, _, dst in links), models)

        self.clean = {
            "state": CleanEpochs({
                s: stream([("formation", s, d) for d in self.out_links[s]])
                for s in self.agents if self.out_links[s]
            }, {j: len(self.in_links[j]) for j in self.agents}),
            "report": CleanEpochs({s: stream([("report", s, LEADER_ENDPOINT)]) for s in self.agents},
                                  {LEADER_ENDPOINT: len(self.agents)}),
            "estimate": CleanEpochs({d: stream([("estimate", LEADER_ENDPOINT, d)]) for d in self.agents},
                                    dict.fromkeys(self.agents, 1)),
        }  # fmt: skip

    def _forward_clean(self, phase: Phase, stream: int, epoch: int, seq: int, payload: Any) -> bool:
        """Take a packet of a clean epoch with no per-packet decision; False when the epoch
        needs the full path. A receiver's delivery goes out once all its senders' are here."""
        ce = self.clean.get(phase)
        if ce is None:
            return False
        clean = ce.flags.get(epoch)
        if clean is None:
            clean = ce.clean(epoch)
        if not clean:  # by the models, or already handled packet by packet
            return False
        receivers = ce.receivers.get(stream)
        if receivers is None or self.dead or self.held:
            self._go_slow(phase, epoch)
            return False
        pending = ce.pending.get(epoch)
        if pending is None:
            pending = ce.pending[epoch] = {}
        elif stream in pending:
            return True  # a second packet of one sender's epoch (not one of ours): ignored
        pending[stream] = seq
        gather = ce.gather.get(epoch)
        if gather is None:
            gather = ce.gather[epoch] = {}
            ce.encoded[epoch] = {}
        packet = ce.encoded[epoch][stream] = packet_json(stream, seq, epoch, 1, payload)
        for r in receivers:
            got = gather.get(r)
            if got is None:
                got = gather[r] = []
            got.append(packet)
            if len(got) >= ce.need[r]:
                gather[r] = _DELIVERED
                self._deliver(phase, r, epoch, got, [], [])
                # Epochs into a receiver finish in order: its senders need its previous one.
                self.next_close[(phase, r)] = epoch + 1
        if len(pending) >= ce.expected:
            del ce.pending[epoch], ce.gather[epoch], ce.encoded[epoch]
            ce.finish(epoch, pending)
            if len(ce.chunks) >= _FLUSH_CHUNKS or epoch >= self.epochs - 1:
                self._flush_clean(phase)  # the last epoch's go out while the run still goes
        return True

    def _flush_clean(self, phase: Phase) -> None:
        """Publish the records of the clean epochs finished since the last flush, in one batch."""
        ce = self.clean.get(phase)
        if ce is None or not ce.chunks:
            return
        key = keys.netem_decision(self.run_id)
        header = self.service.header(key, ce.last_done)
        self.service.put(key, decision_batch_of(header, phase, ce.chunks))
        ce.chunks = []

    def _go_slow(self, phase: Phase, epoch: int) -> None:
        """From now on ``epoch`` of ``phase`` takes the full path; what went fast is recorded as such."""
        ce = self.clean[phase]
        ce.mark_slow(epoch)
        got = ce.pending.pop(epoch, None)
        gather = ce.gather.pop(epoch, {})
        encoded = ce.encoded.pop(epoch, {})
        if got is None:
            return
        touched: set[int] = set()
        for (src, dst, cls, _, seq, d), link in ce.records(epoch, got):
            self.decisions[(phase, epoch)].append((src, dst, cls, epoch, seq, d))
            self.forwarded[link] += 1  # type: ignore[index]
            if gather.get(dst) is _DELIVERED:
                continue
            box = self.open.get((phase, dst, epoch))
            if box is None:
                box = self.open[(phase, dst, epoch)] = _Open()
            box.handled.add(src)
            box.packets.append(encoded[src])
            touched.add(dst)
        self.closed_count[(phase, epoch)] += sum(p is _DELIVERED for p in gather.values())
        for dst in touched:
            self._try_close(phase, dst)

    def _senders(self, phase: Phase, receiver: int) -> list[int]:
        if phase == "state":
            return self.in_links[receiver]
        if phase == "report":
            return self.agents
        return [LEADER_ENDPOINT]

    def _all_handled(self, box: _Open, senders: list[int]) -> bool:
        if not self.dead:  # a receiver only hears from its senders: counting is enough
            return len(box.handled) >= len(senders)
        return all(s in box.handled for s in senders if s not in self.dead)

    def _try_close(self, phase: Phase, receiver: int) -> None:
        senders = self._senders(phase, receiver)
        while True:
            epoch = self.next_close[(phase, receiver)]
            box = self.open.get((phase, receiver, epoch))
            if box is None:
                if epoch >= self.scenario.epochs or any(s not in self.dead for s in senders):
                    return
                box = _Open()  # every sender is dead: close the epoch empty
            elif not self._all_handled(box, senders):
                return
            self.open.pop((phase, receiver, epoch), None)
            for h in self.held.pop((phase, receiver, epoch), []):
                self.forwarded[h.link] += h.copies
                box.packets.append(h.packet)
            dead = [s for s in senders if s in self.dead] if self.dead else []
            self._deliver(phase, receiver, epoch, box.packets, box.lost, dead)
            self.next_close[(phase, receiver)] = epoch + 1
            self.closed_count[(phase, epoch)] += 1
            receivers = len(self.agents) - len(self.dead) if phase != "report" else 1
            if self.closed_count[(phase, epoch)] >= receivers:
                del self.closed_count[(phase, epoch)]
                self._publish_decisions(phase, epoch)

    def _publish_decisions(self, phase: Phase, epoch: int) -> None:
        batch = self.decisions.pop((phase, epoch), [])
        self._flush_clean(phase)  # records stay in epoch order
        key = keys.netem_decision(self.run_id)
        self.service.put(key, decision_batch(self.service.header(key, epoch), phase, batch))

    # -- inbound ----------------------------------------------------------------------------------
    def _on_sample(self, sample: zenoh.Sample) -> None:
        """Every inbound packet: handled at once on Zenoh's thread in lockstep, else queued."""
        att = sample.attachment
        if not self.running:
            raw = None if att is None else att.to_bytes()
            self.service.inbox.put(Incoming(str(sample.key_expr), sample.payload.to_bytes(), raw))
            return
        key = str(sample.key_expr)
        self.service.handle_inline(key, self._handle, key, sample.payload, att)

    def handle(self, msg: Incoming) -> None:
        """A queued packet (one that came before the start)."""
        self._handle(msg.key, msg.payload, msg.attachment)

    def _route_of(self, key: str) -> _Route | None:
        """``(kind, source, target)`` of an inbound key, parsed once per key; None if not ours.

        ``agent/<i>/state`` and ``agent/<i>/report`` come from ``i`` (target unused, 0);
        ``leader/estimate/<i>`` from the leader to ``i``.
        """
        if key not in self._routes:
            parts = key.split("/")
            route: _Route | None = None
            if len(parts) == 5 and parts[3].isdigit() and int(parts[3]) in self.agents:
                if parts[2] == "agent" and parts[4] in ("state", "report"):
                    route = (parts[4], int(parts[3]), 0)
            elif (
                len(parts) == 5
                and parts[2:4] == ["leader", "estimate"]
                and parts[4].isdigit()
                and int(parts[4]) in self.agents
            ):
                route = ("estimate", LEADER_ENDPOINT, int(parts[4]))
            self._routes[key] = route
        return self._routes[key]

    def _estimate_handled(self, epoch: int) -> None:
        """The leader sends one estimate per agent: the epoch is done once all were handled."""
        self._estimates_seen[epoch] += 1
        if self._estimates_seen[epoch] >= len(self.agents):
            del self._estimates_seen[epoch]
            self.estimates_done = max(self.estimates_done, epoch + 1)
            self._notify_last_seen()

    def _final_state(self, agent: int) -> None:
        self.final_states.add(agent)
        self._notify_last_seen()

    def _notify_last_seen(self) -> None:
        with self._last_seen:
            self._last_seen.notify_all()

    def _handle(self, key: str, payload: Any, att: Any) -> None:
        raw = att if att is None or isinstance(att, bytes) else att.to_bytes()
        meta = read_attachment(raw)
        route = self._route_of(key)
        if meta is None or route is None or meta[2] != route[1]:
            self.service.malformed.counts[key] += 1
            return
        epoch, seq, source = meta
        kind = route[0]
        if kind == "state":
            if self.passthrough:
                for dst in self.out_links[source]:
                    self._link("formation", source, dst)[0].put(payload, attachment=att)
                return
            if epoch > self.epoch_seen:
                self.epoch_seen = epoch
            if epoch >= self.epochs:
                self._final_state(source)
                return
            if self._forward_clean("state", source, epoch, seq, payload):
                return
            for dst in self.out_links[source]:
                if dst in self.dead:
                    continue
                box = self._route_packet("state", "formation", source, dst, payload, epoch, seq)
                if self._all_handled(box, self.in_links[dst]):  # else nothing can close yet
                    self._try_close("state", dst)
        elif kind == "report":
            if self._forward_clean("report", source, epoch, seq, payload):
                return
            box = self._route_packet(
                "report", "report", source, LEADER_ENDPOINT, payload, epoch, seq
            )
            if self._all_handled(box, self.agents):
                self._try_close("report", LEADER_ENDPOINT)
        else:
            dst = route[2]
            if self._forward_clean("estimate", dst, epoch, seq, payload):
                pass
            elif dst not in self.dead:
                self._route_packet(
                    "estimate", "estimate", LEADER_ENDPOINT, dst, payload, epoch, seq
                )
                self._try_close("estimate", dst)
            self._estimate_handled(epoch)

    def _on_dead(self, agent: int) -> None:
        if agent in self.dead or agent in self.final_states:
            return
        log.warning("agent %d is gone: its packets count as lost from now on", agent)
        self.dead.add(agent)
        for phase, ce in self.clean.items():
            for epoch in list(ce.pending):
                self._go_slow(phase, epoch)
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
        for ce in self.clean.values():
            ce.invalidate()
        key = keys.netem_change(self.run_id)
        change = LinkChange(**self.service.header(key, from_epoch), source=src, target=dst, link_class=cls,
                            models=[s.model_dump(by_alias=True) for s in specs], from_epoch=from_epoch)  # fmt: skip
        self.service.publish(key, change)
        return {"ok": True, "link": link, "class": cls, "from_epoch": from_epoch}

    def _on_final(self, query: zenoh.Query) -> None:
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

    # -- realtime --------------------------------------------------------------------------------------
    def _on_clock(self, query: zenoh.Query) -> None:
        if self.clock is None:
            query.reply_err(b"not started")
        else:
            query.reply(query.key_expr, self.clock.to_json())

    def _forward_realtime(self, cls: LinkClass, src: int, dst: int, msg: Incoming, epoch: int,
                          seq: int, due: list[_Due]) -> None:  # fmt: skip
        assert self.clock is not None
        now = time.time_ns()
        pub, model = self._link(cls, src, dst)
        d = model.decide(epoch, time_s=(now - self.clock.t0_ns) / 1e9)
        self.decisions[(_PHASE_OF[cls], epoch)].append((src, dst, cls, epoch, seq, d))
        if not d.delivered:
            return
        self.forwarded[(cls, src, dst)] += d.copies
        for _ in range(d.copies):
            if d.delay_ms <= 0:
                pub.put(msg.payload, attachment=msg.attachment)
            else:
                due_ns = now + int(d.delay_ms * 1e6)
                heapq.heappush(due, (due_ns, len(due), pub, msg.payload, msg.attachment))

    def _handle_realtime(self, msg: Incoming, due: list[_Due]) -> None:
        meta = read_attachment(msg.attachment)
        route = self._route_of(msg.key)
        if meta is None or route is None or meta[2] != route[1]:
            self.service.malformed.counts[msg.key] += 1
            return
        epoch, seq, source = meta
        kind = route[0]
        if kind == "state":
            self.epoch_seen = max(self.epoch_seen, epoch)
            if epoch >= self.scenario.epochs:
                self._final_state(source)
                return
            for dst in self.out_links[source]:
                self._forward_realtime("formation", source, dst, msg, epoch, seq, due)
        elif kind == "report":
            self._forward_realtime("report", source, LEADER_ENDPOINT, msg, epoch, seq, due)
        else:
            self._forward_realtime("estimate", LEADER_ENDPOINT, route[2], msg, epoch, seq, due)
            self._estimate_handled(epoch)

    def run_realtime(self, period_s: float) -> int:
        """Forward each packet as it comes (after its model's delay in ms); no epoch closes."""
        while not self.everyone_up():
            if self.service.stopping.wait(0.02):
                return 130
        self.clock = Clock(time.time_ns() + int(0.3e9), int(period_s * 1e9))
        self.service.declare_start()
        due: list[_Due] = []
        next_flush = self.clock.at(1)
        while not (self.finished() and not due) and not self.service.stopping.is_set():
            now = time.time_ns()
            while due and due[0][0] <= now:
                _, _, pub, payload, att = heapq.heappop(due)
                pub.put(payload, attachment=att)
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
        with self.lock:  # lockstep: handled on Zenoh's thread from now on, no queue hand-off
            if not self.passthrough:
                self._setup_clean()
            self.running = True
        while not self.everyone_up():
            if self.service.stopping.wait(0.02):
                return 130
        settle_heap()
        self.service.declare_start()
        try:
            return self._lockstep_loop()
        finally:
            self._flush_all()

    def _flush_all(self) -> None:
        with self.lock:
            for phase in self.clean:
                self._flush_clean(phase)

    def _lockstep_loop(self) -> int:
        while not self.finished() and not self.service.stopping.is_set():
            msg = self.service.next_incoming(0.2)
            self._check_dead()
            self._flush_all()  # clean epochs' records wait at most this long
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
