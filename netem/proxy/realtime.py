"""netem in realtime: each packet forwarded as it comes, after its delay, batched per receiver.

No epoch closes: a link's model decides each packet from its epoch and the time since
the clock's start (a realtime outage), and a delayed packet waits in a heap until due.
What one wake-up forwards to a receiver in a phase goes out as one :class:`Delivery` on
``inbox/<receiver>/<phase>`` (``lost`` and ``dead`` empty: nothing closes), not one
message per link: a burst of states crosses Zenoh as a message per receiver, which cut
the puts 2-2.5x (20 agents at 20 Hz; 100 pooled at 10 Hz).
The decision records go out once per period (at :data:`RECORDS_AT` of it, when netem
idles), one batch per phase and epoch.

Packets are queued by Zenoh's threads and handled here, on the main thread, a whole queue
at a time, so Zenoh's threads never wait on netem. Handled where it arrived, a packet kept
its receiving thread in a blocking put; under overload (100 and 200 agents at 20 Hz) two
runs then stalled for 30 s, the router, netem and the agents waiting on each other.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import math
import threading
import time
from collections import Counter, defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from itertools import islice
from typing import Any, NamedTuple

import numpy as np

from formation.codec import read_attachment
from formation.deadlines import PHASES
from formation.keys import LEADER_ENDPOINT
from formation.realtime import Clock
from netem.links.air_network import AIR, AirVerdict
from netem.links.layer_stack import Outcome
from netem.proxy.progress import Progress
from netem.proxy.realtime_air import RealtimeAir
from netem.proxy.records import Ledger, Queued, Record, message_json, packet_json_of, queued
from netem.proxy.routes import PHASE_OF, Link, LinkClass, Links, Phase, Routes
from shell import Incoming, Service, TimePolicy

Inbox = tuple[Phase, int]  # (phase, receiver)
# (due ns, token, its receiver's inbox, sent epoch, packet JSON, copies, its phase's deadline ns)
Due = tuple[int, int, Inbox, int, bytes, int, int]
KIND_OF: dict[LinkClass, str] = {"formation": "state", "report": "report", "estimate": "estimate"}
PublishRecords = Callable[[Phase, int, list[Record]], None]
# (phase, receiver, epoch, packets, lost, dead): netem.node.ZenohOutbox.deliver
Deliver = Callable[[Phase, int, int, list[bytes], list[int], list[int]], None]
# A burst is flushed at least this often while netem works through it: batching must not
# hold the first packets back until the last is decided [ns].
FLUSH_NS = 1_000_000
# The decision records go out once a period at this fraction of it, when netem idles: the
# agents report at the state deadline (0.20), the leader estimates once every report is in
# and each agent steps once its estimate is in, so the states mostly left by 0.5; an agent
# whose estimate is late steps at its deadline (0.85). At 0.0 the records landed in the
# states' burst, on netem and on every subscriber.
RECORDS_AT = 0.70
# Link models decide in blocks of epochs, computed at a block's first decision. netem
# computes them ahead instead: every model's first before the clock starts (else the first
# epochs went out late: 8 ms of decisions at 20 agents, 67 ms at 100, against 0.3 and 2.5 ms
# an epoch after), and each next one within this many epochs before it is needed, a share of
# the links per period, at the records' quiet time.
PREPARE_AHEAD = 32
# The clock starts this long after everyone is up: every agent must fetch it and publish
# x[0] before epoch 0. At 0.3 s, agents of a 20-process team on 2 cores were late with x[0].
START_LEAD_S = 1.0
log = logging.getLogger("netem")


@dataclass
class _Outgoing:
    """What one receiver's inbox gets at the next flush."""

    epoch: int = -1  # the newest packet's sent epoch
    packets: list[bytes] = field(default_factory=list)
    # (ready ns, deadline ns, copies): ready (arrived, or its delay over) by the deadline,
    # but put out after it, a packet is netem's miss ("late_forwards")
    timing: list[tuple[int, int, int]] = field(default_factory=list)


class _Held(NamedTuple):
    """A packet its queues hold: its phase and link, its record (once it leaves), the model's
    decision, when it came [ns], and whether it was counted past its deadline (for any reason,
    by its queues)."""

    phase: Phase
    link: Link
    record: Record
    model: Outcome
    arrived_ns: int
    past: bool
    queue_past: bool


class RealtimeForwarder:
    """Forwards packets after their models' delays, batched per receiver (:meth:`flush`)."""

    def __init__(
        self,
        service: Service,
        links: Links,
        routes: Routes,
        progress: Progress,
        ledger: Ledger,
        publish_records: PublishRecords,
        deliver: Deliver,
        lock: threading.Lock | None = None,
    ) -> None:
        self.service, self.links, self.routes = service, links, routes
        self.lock = threading.Lock() if lock is None else lock  # shared with the node's handlers
        self.progress, self.ledger, self.publish_records = progress, ledger, publish_records
        self.deliver = deliver
        self.clock: Clock | None = None  # set by begin()
        self._due: list[Due] = []
        self._next_records = 0
        # modelled_late: packets a model delayed past their deadline (modelled losses);
        # late_forwards: packets in time here (and by their model) put out after it
        self.deadline: Counter[str] = Counter()
        self._out: defaultdict[Inbox, _Outgoing] = defaultdict(_Outgoing)
        self._oldest_ns = 0  # when the oldest unflushed packet was queued (0: none)
        self._tokens = itertools.count()  # names each packet in the queues and the heap
        self._held: dict[int, _Held] = {}  # packets a queue holds, by token
        self._pushed: set[int] = set()  # held packets pushed out, still in the heap
        self.last_state: dict[int, tuple[int, Any]] = {}  # agent → (epoch, payload) last handled
        # the shared air: its phases' packets, held until the model's arrival
        self.air = None if links.air is None else RealtimeAir(links.air)
        self._aired: set[int] = set()  # tokens of packets the air delivered, in the heap

    def forward(
        self,
        cls: LinkClass,
        src: int,
        dst: int,
        msg: Incoming,
        epoch: int,
        seq: int,
        text: bytes,
        due: list[Due],
        size: int = 0,
    ) -> None:
        """Decide one packet on one link: out at the next flush, pushed on ``due``, or dropped.

        ``text``: the payload as a JSON string (:func:`~netem.proxy.records.message_json`), once
        for every link it takes; ``size``: the payload's bytes, what its capacity queues count."""
        assert self.clock is not None
        now = time.time_ns()
        t0 = self.clock.t0_ns
        o = self.links.models[(cls, src, dst)].decide(epoch, time_s=(now - t0) / 1e9)
        d: Outcome | Queued = o
        phase = PHASE_OF[cls]
        deadline_ns = self.clock.at(epoch, PHASES[KIND_OF[cls]][1])
        held_ns = 0  # [ns] in the capacity queues (docs/model.md §9)
        queues = self.links.capacity
        token = next(self._tokens)
        if o.delivered and queues is not None and queues.constrained((src, dst), epoch):
            v, leaves_s, pushed = queues.arrive(
                (src, dst), size, (now - t0) / 1e9, epoch, (deadline_ns - t0) / 1e9, token
            )
            for victim in pushed:
                self._push_out(victim, v.queue, now)
            for held, leaves in queues.retimed().items():  # their time given back
                self._retime(held, leaves, due)
            if v.reason and v.reason != "queue_late":  # refused: a queue's drop
                d = queued(o, v.reason, v.queue, v.depth, v.sojourn_ms)
                self.deadline["queue_drops"] += 1
            else:  # held until it leaves, however late: the receiver sees it when it would
                late = v.reason or o.model
                d = Queued(
                    o.delivered,
                    o.delay_epochs,
                    o.delay_ms,
                    o.copies,
                    o.verdict,
                    late,
                    o.state,
                    o.reordered,
                    v.queue,
                    v.depth,
                    v.sojourn_ms,
                )
                held_ns = max(0, int(leaves_s * 1e9) + t0 - now)
        record: Record = (src, dst, cls, epoch, seq, d)
        if o.delivered and self.air is not None and self.air.carries((src, dst)):
            came = msg.arrived_ns or now  # held until the air's phase settles it (tick)
            item = (record, o, packet_json_of(src, seq, epoch, o.copies, text), deadline_ns)
            self.air.add(epoch, phase, (src, dst), came, deadline_ns, item)
            return
        if not d.delivered:
            self.ledger.decisions[(phase, epoch)].append(record)
            return
        self.ledger.forwarded[(cls, src, dst)] += d.copies
        packet = packet_json_of(src, seq, epoch, d.copies, text)
        if d.delay_ms <= 0 and not held_ns:
            self.ledger.decisions[(phase, epoch)].append(record)
            self.queue((phase, dst), epoch, packet, msg.arrived_ns, deadline_ns, d.copies)
            return
        due_ns = now + held_ns + int(d.delay_ms * 1e6)
        past = due_ns > deadline_ns
        queue_past = past and bool(held_ns) and now + held_ns > deadline_ns
        if past:
            self.deadline["modelled_late"] += d.copies
            if queue_past:
                self.deadline["queue_late"] += d.copies  # of them, late by its queues
        if held_ns:  # a queue may still push it out: its record once it leaves (tick)
            self._held[token] = _Held(phase, (cls, src, dst), record, o, now, past, queue_past)
        else:
            self.ledger.decisions[(phase, epoch)].append(record)
        heapq.heappush(due, (due_ns, token, (phase, dst), epoch, packet, d.copies, deadline_ns))

    def _push_out(self, token: int, queue: str, now: int) -> None:
        """A held packet pushed out of ``queue`` (``oldest``) by a newer one: dropped, as if
        refused (``queue_full``), never forwarded."""
        h = self._held.pop(token, None)
        if h is None:
            return  # it left already
        self._pushed.add(token)
        src, dst, cls, epoch, seq, d = h.record
        self.ledger.forwarded[h.link] -= d.copies
        if h.past:
            self.deadline["modelled_late"] -= d.copies
        if h.queue_past:
            self.deadline["queue_late"] -= d.copies
        self.deadline["queue_drops"] += 1
        dropped = queued(h.model, "queue_full", queue, 0, (now - h.arrived_ns) / 1e6)
        self.ledger.decisions[(h.phase, epoch)].append((src, dst, cls, epoch, seq, dropped))

    def _retime(self, token: int, leaves_s: float, due: list[Due]) -> None:
        """A held packet leaves its queues at ``leaves_s`` [s since the clock's start] instead,
        as packets pushed out ahead of it gave their time back: due then, its record and
        deadline counts as if it had been given that departure as it came."""
        h = self._held.get(token)
        at = next((i for i, entry in enumerate(due) if entry[1] == token), None)
        if h is None or at is None or self.clock is None:
            return  # it left already
        _, _, inbox, epoch, packet, copies, deadline_ns = due[at]
        t0 = self.clock.t0_ns
        leaves_ns = int(leaves_s * 1e9) + t0
        due_ns = max(h.arrived_ns, leaves_ns) + int(h.model.delay_ms * 1e6)
        due[at] = (due_ns, token, inbox, epoch, packet, copies, deadline_ns)
        heapq.heapify(due)
        past = due_ns > deadline_ns
        queue_past = past and h.arrived_ns < leaves_ns and leaves_ns > deadline_ns
        self.deadline["modelled_late"] += (past - h.past) * copies
        self.deadline["queue_late"] += (queue_past - h.queue_past) * copies
        src, dst, cls, _, seq, d = h.record
        if isinstance(d, Queued):
            late = "queue_late" if leaves_ns > deadline_ns else h.model.model
            sojourn_ms = (leaves_ns - h.arrived_ns) / 1e6
            d = d._replace(model=late, sojourn_ms=sojourn_ms)
        record: Record = (src, dst, cls, epoch, seq, d)
        self._held[token] = h._replace(record=record, past=past, queue_past=queue_past)

    def queue(
        self, inbox: Inbox, epoch: int, packet: bytes, ready_ns: int, deadline_ns: int, copies: int
    ) -> None:
        """A packet for ``inbox`` at the next flush."""
        out = self._out[inbox]
        out.packets.append(packet)
        out.epoch = max(out.epoch, epoch)
        if ready_ns <= deadline_ns:
            out.timing.append((ready_ns, deadline_ns, copies))
        if not self._oldest_ns:
            self._oldest_ns = time.time_ns()

    def flush(self, unless_newer_than_ns: int = 0) -> None:
        """One delivery per receiver's inbox of everything queued since the last flush; with
        ``unless_newer_than_ns``, only once the oldest has waited that long."""
        if not self._oldest_ns or time.time_ns() - self._oldest_ns < unless_newer_than_ns:
            return
        out, self._out, self._oldest_ns = self._out, defaultdict(_Outgoing), 0
        for (phase, receiver), o in out.items():
            now = time.time_ns()
            self.deadline["late_forwards"] += sum(c for _, dl, c in o.timing if dl < now)
            self.deliver(phase, receiver, o.epoch, o.packets, [], [])

    def handle(self, msg: Incoming, due: list[Due]) -> None:
        """One inbound packet: forwarded on each of its links (a final state only noted)."""
        meta = read_attachment(msg.attachment)
        route = self.routes.of(msg.key)
        if meta is None or route is None or meta[2] != route[1]:
            self.service.malformed.counts[msg.key] += 1
            return
        epoch, seq, source = meta
        kind = route[0]
        progress = self.progress
        if kind == "state":
            progress.epoch_seen = max(progress.epoch_seen, epoch)
            self.last_state[source] = (epoch, msg.payload)  # where a restart takes its body from
            if epoch >= progress.epochs:
                progress.final_state(source)
                return
            text = message_json(msg.payload)
            size = _size(msg.payload)
            if self.air is not None:
                payload = msg.payload
                raw = payload if isinstance(payload, bytes) else payload.to_bytes()
                self.air.read_position(epoch, source, raw)
            for dst in self.links.out_links[source]:
                if self.takes_part(dst, epoch):
                    self.forward("formation", source, dst, msg, epoch, seq, text, due, size)
        elif kind == "report":
            text = message_json(msg.payload)
            size = _size(msg.payload)
            self.forward("report", source, LEADER_ENDPOINT, msg, epoch, seq, text, due, size)
        else:
            text = message_json(msg.payload)
            size = _size(msg.payload)
            if self.takes_part(route[2], epoch):
                self.forward(
                    "estimate", LEADER_ENDPOINT, route[2], msg, epoch, seq, text, due, size
                )
            progress.estimate_handled(epoch)

    def takes_part(self, agent: int, epoch: int) -> bool:
        """Whether ``agent`` is in the team at ``epoch`` by the scenario's events: nothing is
        sent to an agent before it joins, after it leaves or while it is down by a crash."""
        team = self.links.team
        return (
            team is None
            or not 0 <= epoch < len(team.present)
            or bool(team.present[epoch, agent - 1])
        )

    def prepare(self, epoch: int) -> None:
        """The decision blocks of epoch ``epoch + PREPARE_AHEAD``, for one link in
        ``PREPARE_AHEAD`` (a different share each epoch)."""
        share = islice(self.links.models.values(), epoch % PREPARE_AHEAD, None, PREPARE_AHEAD)
        for model in share:
            model.prepare(epoch + PREPARE_AHEAD)

    def publish_decisions(self) -> None:
        """Every record not yet published, one batch per phase and epoch, in order."""
        decisions = self.ledger.decisions
        for phase, epoch in sorted(decisions):
            self.publish_records(phase, epoch, decisions.pop((phase, epoch), []))

    # -- the wake-ups of netem's loop (netem.proxy.loop.run_loop) ----------------------------------------
    def open(self) -> None:
        """Nothing before everyone is up: packets queue until the clock starts."""

    def begin(self, timing: TimePolicy) -> None:
        """Every model's first block of decisions, then the clock (``START_LEAD_S`` ahead)."""
        for model in self.links.models.values():
            model.prepare(0)
        timing.begin(self.service, lead_s=START_LEAD_S)
        self.clock = timing.clock
        assert self.clock is not None  # a realtime policy's
        self._due = []  # delayed packets, by due time
        self._next_records = self.clock.at(0, RECORDS_AT)

    def idle(self) -> bool:
        """Whether no delayed packet is still to be forwarded."""
        return not self._due

    def tick(self) -> float:
        """Forward what is due now and flush; publish the records once a period. Returns how
        long to wait for a packet [s]: until the next due packet or records, at most 0.05."""
        assert self.clock is not None
        due = self._due
        now = time.time_ns()
        with self.lock:
            if self.air is not None:
                for item, verdict, at_ns in self.air.settle(now):
                    self._on_air(item, verdict, at_ns, due)
            while due and due[0][0] <= now:
                due_ns, token, inbox, epoch, packet, copies, deadline_ns = heapq.heappop(due)
                if token in self._aired and self.air is not None:
                    self._aired.discard(token)
                    self.air.lag_ns.append(now - due_ns)
                if token in self._pushed:  # pushed out of its queue while held
                    self._pushed.discard(token)
                    continue
                held = self._held.pop(token, None)
                if held is not None:  # it left its queues: its fate is known
                    self.ledger.decisions[(held.phase, epoch)].append(held.record)
                self.queue(inbox, epoch, packet, due_ns, deadline_ns, copies)
            self.flush()
            if now >= self._next_records:
                self.publish_decisions()
                self.prepare(self.clock.epoch_of(self._next_records))
                self._next_records += self.clock.period_ns
        until = min(self._next_records, due[0][0]) if due else self._next_records
        settles = None if self.air is None else self.air.next_ns()
        if settles is not None:
            until = min(until, settles)
        return max(0.0, min(0.05, (until - now) / 1e9))

    def _on_air(self, item: Any, verdict: AirVerdict, at_ns: int, due: list[Due]) -> None:
        """A packet whose fate on the air is settled: recorded; if delivered, due at its
        arrival (and its model's delay)."""
        (src, dst, cls, epoch, seq, _), o, packet, deadline_ns = item
        phase = PHASE_OF[cls]
        if not verdict.passed:
            d = queued(o, verdict.cause, AIR, verdict.frames, math.nan)
            self.ledger.decisions[(phase, epoch)].append((src, dst, cls, epoch, seq, d))
            return
        d = queued(o, "", AIR, verdict.frames, verdict.arrival_ms)
        self.ledger.decisions[(phase, epoch)].append((src, dst, cls, epoch, seq, d))
        self.ledger.forwarded[(cls, src, dst)] += o.copies
        token = next(self._tokens)
        due_ns = at_ns + int(o.delay_ms * 1e6)
        if o.delay_ms <= 0:
            self._aired.add(token)
        if due_ns > deadline_ns:
            self.deadline["modelled_late"] += o.copies
        heapq.heappush(due, (due_ns, token, (phase, dst), epoch, packet, o.copies, deadline_ns))

    def wake(self, msg: Incoming | None) -> None:
        """The packet that woke netem and every other one queued, handled at once."""
        if msg is None:
            return
        service, due = self.service, self._due
        with self.lock:
            self.handle(msg, due)
            while (more := service.next_incoming(0)) is not None:
                self.handle(more, due)
                self.flush(unless_newer_than_ns=FLUSH_NS)
            self.flush()

    def end(self) -> None:
        with self.lock:
            if self.air is not None:
                for item, verdict, at_ns in self.air.settle(1 << 62):  # what was still open
                    self._on_air(item, verdict, at_ns, [])
            self.publish_decisions()
        if self.air is not None and self.air.lag_ns:
            lag = np.array(self.air.lag_ns) / 1e3  # [µs]
            log.info(
                "air: %d packets put out after the model's arrival by median %.0f µs, "
                "99th percentile %.0f µs, max %.0f µs",
                lag.size,
                np.median(lag),
                np.percentile(lag, 99),
                lag.max(),
            )


def _size(payload: Any) -> int:
    """A payload's bytes on the wire (bytes, or Zenoh's ZBytes)."""
    return len(payload) if isinstance(payload, bytes) else len(payload.to_bytes())
