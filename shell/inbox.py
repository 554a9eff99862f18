"""A node's phase inbox: what netem delivered to its receivers, taken one phase at a time.

The fork between the modes lives here, not in the nodes (docs/architecture.md "Time"). A
node files every message with :meth:`PhaseInbox.route` and takes a phase's inputs in one
line, ``got = yield from inbox.take(phase, epoch)``; its time policy chose the form:

- :class:`LockstepInbox`: netem's delivery of ``(receiver, phase, epoch)`` closes the phase;
  the phase's inputs are its packets. A pool's deliveries may come batched
  (:class:`~formation.messages.DeliveryBatch`), each filed as if it came alone; a packet
  the batch carries once is decoded once for all its receivers.
- :class:`RealtimeInbox`: what netem forwarded, filed by epoch; the phase ends at its
  deadline, or once every receiver has a packet from ``expect`` senders. A packet of an
  epoch already taken missed its deadline: counted by cause (:mod:`formation.deadlines`),
  unless it is a copy of one used, in time. It owns that memory of used packets.
"""

from __future__ import annotations

from collections.abc import (
    Callable,
    Generator,
    Hashable,
    Iterable,
    Iterator,
    Mapping,
    MutableMapping,
)
from dataclasses import dataclass
from functools import partial
from itertools import chain, filterfalse, repeat
from operator import attrgetter, itemgetter
from typing import Any, Literal, Protocol

import numpy as np
import numpy.typing as npt
from pydantic import BaseModel

from formation import keys
from formation.codec import batched_deliveries, payloads
from formation.deadlines import PHASES, USED_KEPT, cause
from formation.messages import (
    AgentEstimate,
    CoordinationState,
    DeliveredPacket,
    Delivery,
    DeliveryBatch,
    TokenReport,
)
from formation.realtime import Clock
from formation.structs import decoder_of
from shell.loop import Wait
from shell.service import Incoming, Service

Inputs = dict[int, Iterable[tuple[DeliveredPacket, Any]]]  # receiver → (packet, payload)s
Take = Generator[Wait, bool, Inputs]  # ``yield from`` it in a node's loop
Filed = tuple[Any, list[Any], list[int]]  # a delivery's fields, a packet table, its packets' rows
Ids = npt.NDArray[np.int64]


@dataclass(frozen=True)
class Columns:
    """A phase's inputs as columns: each (receiver, packet) pair whose payload is valid and
    its link's, in delivery order, and each distinct packet once (a pool's batch carries a
    packet to several receivers).

    receiver : (m,) the pair's receiver; entry : (m,) its packet's row in ``packets`` and
    ``payloads`` (the message, decoded; None where invalid); source, sent_epoch : (e,) of
    each packet.
    """

    receiver: Ids
    entry: Ids
    packets: list[DeliveredPacket]
    payloads: list[Any]
    source: Ids
    sent_epoch: Ids

    @classmethod
    def of(cls, got: Inputs) -> Columns:
        """The pairs of ``got`` (every one valid), each its own entry."""
        pairs = [(r, p, m) for r, taken in got.items() for p, m in taken]
        packets = [p for _, p, _ in pairs]
        return cls(
            np.array([r for r, _, _ in pairs], dtype=np.int64),
            np.arange(len(pairs), dtype=np.int64),
            packets,
            [m for _, _, m in pairs],
            np.array([p.source for p in packets], dtype=np.int64),
            np.array([p.sent_epoch for p in packets], dtype=np.int64),
        )


@dataclass(frozen=True)
class Kind:
    """What a phase carries and how a receiver reads and counts it."""

    model: type[BaseModel]
    link: Callable[[str, int, DeliveredPacket], str]  # (run, receiver, packet) → its link's key
    owner: Literal["source", "receiver"]  # the agent a payload must name for its link to carry it
    epoch: Callable[[DeliveredPacket, Any], int]  # the epoch it is an input of
    key: Callable[[DeliveredPacket, Any], Hashable]  # realtime: one filed per key (a copy replaces)
    delayed: bool  # lockstep: packets delayed from earlier epochs are inputs too
    copies: bool  # realtime: a copy of a used packet that came in time is no miss
    taken: str | None  # the count of packets taken in time, if the node keeps one
    late: str | None  # the count of packets that missed the deadline, if kept

    def belongs(self, receiver: int, p: DeliveredPacket, m: Any) -> bool:
        """Whether the link of ``p`` into ``receiver`` can carry payload ``m``."""
        return bool(m.agent == (p.source if self.owner == "source" else receiver))


KINDS: Mapping[str, Kind] = {
    "state": Kind(
        CoordinationState,
        lambda run, i, p: keys.link_state(run, p.source, i),
        "source",
        lambda p, m: p.sent_epoch,
        lambda p, m: (p.source, p.seq),
        delayed=True,
        copies=False,
        taken="packets",
        late="late_packets",
    ),
    "estimate": Kind(
        AgentEstimate,
        lambda run, i, p: keys.link_estimate(run, i),
        "receiver",  # another agent's part is unusable
        lambda p, m: m.epoch,
        lambda p, m: m.epoch,
        delayed=False,
        copies=True,
        taken="estimates",
        late="late_estimates",
    ),
    "report": Kind(
        TokenReport,
        lambda run, i, p: keys.link_report(run, p.source),
        "source",
        lambda p, m: m.epoch,
        lambda p, m: (m.agent, m.seq),
        delayed=False,
        copies=True,
        taken=None,
        late=None,
    ),
}


class PhaseInbox(Protocol):
    """A node's receivers' inputs, phase by phase, in its time policy's form."""

    def route(self, msg: Incoming) -> None:
        """File one message from netem (a :class:`Delivery`); count it if it is not one."""
        ...

    def take(self, phase: str, epoch: int, expect: int | None = None, early: str = "") -> Take:
        """Wait for epoch ``epoch``'s inputs of ``phase`` and return them, per receiver.

        ``expect``: realtime, the phase is complete once every receiver has a packet from
        this many senders (None: it waits for the deadline). ``early``: the count of phases
        that ended before their deadline (realtime), if the node keeps one.
        """
        ...

    def take_columns(
        self, phase: str, epoch: int, expect: int | None = None, early: str = ""
    ) -> Generator[Wait, bool, Columns]:
        """:meth:`take`'s inputs as :class:`Columns`."""
        ...


class _Receivers:
    """What both forms share: the receivers, their phases' kinds, the delivery check."""

    def __init__(
        self, service: Service, receivers: Iterable[int], counts: MutableMapping[str, int]
    ) -> None:
        self.service, self.run_id = service, service.run_id
        self.receivers = list(receivers)
        self._ours = set(self.receivers)  # a pool of hundreds looks each delivery up
        self.counts = counts  # the node's status counts: realtime writes into them
        decoder_of(Delivery)  # the decoders made now, before the run's clock starts
        decoder_of(DeliveryBatch)
        for kind in KINDS.values():
            decoder_of(kind.model)

    def _deliveries(self, msg: Incoming) -> list[Filed]:
        """netem's deliveries in ``msg`` (their fields, :meth:`~formation.codec.Malformed.read`)
        that are for these receivers on their own key, each with a packet table and its
        packets' rows there: one, or a pool's batch of them (sharing the batch's table)."""
        if keys.parse(msg.key).kind == "inbox_pool":
            return self._batch(msg)
        delivery = self.service.malformed.read(msg.key, msg.payload, Delivery)
        if delivery is None:
            return []
        receiver = delivery.receiver
        if receiver not in self._ours or not msg.key.endswith(f"/{receiver}/{delivery.phase}"):
            self.service.malformed.counts[msg.key] += 1  # another receiver's: unusable
            return []
        return [(delivery, delivery.packets, list(range(len(delivery.packets))))]

    def _batch(self, msg: Incoming) -> list[Filed]:
        """A pool's batch: its deliveries for these receivers of the batch's phase; one for
        another receiver or phase, or malformed, is counted on the batch's key and skipped."""
        malformed = self.service.malformed
        batch = malformed.read(msg.key, msg.payload, DeliveryBatch)
        if batch is None:
            return []
        unpacked = batched_deliveries(batch)
        if unpacked is None or not msg.key.endswith(f"/pool/{batch.pool}/{batch.phase}"):
            malformed.counts[msg.key] += 1  # another pool's or phase's, or unreadable: unusable
            return []
        table, phase = batch.packets, batch.phase
        ours = [
            (d, table, ids) for d, ids in unpacked if d.receiver in self._ours and d.phase == phase
        ]
        if len(ours) < len(batch.deliveries):
            malformed.counts[msg.key] += len(batch.deliveries) - len(ours)
        return ours

    def _decode(
        self,
        kind: Kind,
        receiver: int,
        packets: Iterable[DeliveredPacket],
        memo: dict[int, tuple[DeliveredPacket, Any]] | None = None,
    ) -> Iterator[tuple[DeliveredPacket, Any]]:
        """The valid payloads; a malformed one is counted on its link's key and lost.
        ``memo``: the packets decoded for other receivers, shared among them."""
        return self.service.malformed.decode_packets(
            packets,
            kind.model,
            partial(kind.link, self.run_id, receiver),
            partial(kind.belongs, receiver),
            memo,
        )


class LockstepInbox(_Receivers):
    """Lockstep: a phase ends once netem's delivery of it is in for every receiver."""

    def __init__(
        self, service: Service, receivers: Iterable[int], counts: MutableMapping[str, int]
    ) -> None:
        super().__init__(service, receivers, counts)
        # (receiver, phase, epoch) → a Delivery's fields, a packet table, its packets' rows
        self.deliveries: dict[tuple[int, str, int], Filed] = {}
        self.floor: dict[str, int] = {}  # phase → the first epoch not yet taken
        self.current: tuple[str, int] | None = None  # the phase and epoch waited for
        self.waiting: set[int] = set()  # its receivers without their delivery yet

    def route(self, msg: Incoming) -> None:
        filed = self._deliveries(msg)
        deliveries = list(map(_DELIVERY, filed))
        when = set(map(_PHASE_EPOCH, deliveries))
        if len(when) == 1:  # a pool's batch, or one delivery: filed at once
            ((phase, epoch),) = when
            if epoch >= self.floor.get(phase, 0):
                self.deliveries.update(zip(map(_WHERE, deliveries), filed, strict=True))
                if self.current == (phase, epoch):
                    self.waiting.difference_update(map(_RECEIVER, deliveries))
            return
        for delivery, table, ids in filed:
            if delivery.epoch < self.floor.get(delivery.phase, 0):
                continue  # a copy of one already used
            receiver, phase = delivery.receiver, delivery.phase
            self.deliveries[(receiver, phase, delivery.epoch)] = (delivery, table, ids)
            # only the receiver a delivery is for can become ready: a pool of hundreds checks one
            if self.current == (phase, delivery.epoch):
                self.waiting.discard(receiver)

    def _all_in(self) -> bool:
        return not self.waiting

    def _filed(self, phase: str, epoch: int) -> Generator[Wait, bool, list[Filed]]:
        """Wait for each receiver's delivery of ``phase`` and ``epoch``; in receiver order."""
        self.current = (phase, epoch)
        where = list(zip(self.receivers, repeat(phase), repeat(epoch), strict=False))
        self.waiting = set(map(_FIRST, filterfalse(self.deliveries.__contains__, where)))
        yield Wait(epoch, PHASES[phase][1], self._all_in)
        self.current, self.floor[phase] = None, epoch + 1
        return list(map(self.deliveries.pop, where))

    def take(self, phase: str, epoch: int, expect: int | None = None, early: str = "") -> Take:
        filed = yield from self._filed(phase, epoch)
        kind = KINDS[phase]
        got: Inputs = {}
        memo: dict[int, tuple[DeliveredPacket, Any]] = {}
        for r, (_, table, ids) in zip(self.receivers, filed, strict=True):
            packets = [table[i] for i in ids]
            current = packets if kind.delayed else [p for p in packets if p.sent_epoch == epoch]
            got[r] = self._decode(kind, r, current, memo)
        return got

    def take_columns(
        self, phase: str, epoch: int, expect: int | None = None, early: str = ""
    ) -> Generator[Wait, bool, Columns]:
        filed = yield from self._filed(phase, epoch)
        return self._columns(KINDS[phase], epoch, filed)

    def _columns(self, kind: Kind, epoch: int, filed: list[Filed]) -> Columns:
        """The pairs of ``filed`` as columns, each distinct packet decoded once; a pair whose
        payload is malformed or not its link's is counted on that link's key and left out."""
        tables, each = list(map(_TABLE, filed)), list(map(_ROWS, filed))
        counts = list(map(len, each))
        receiver = np.repeat(np.array(self.receivers, dtype=np.int64), counts)
        if len(set(map(id, tables))) <= 1:  # a pool's batch: one table
            packets, rows = (tables[0] if tables else []), chain.from_iterable(each)
        else:
            offsets: dict[int, int] = {}  # a table's first row among all the tables' packets
            packets = []
            for _, table, _ in filed:
                if offsets.setdefault(id(table), len(packets)) == len(packets):
                    packets.extend(table)
            rows = chain.from_iterable([i + offsets[id(t)] for i in ids] for _, t, ids in filed)
        entry = np.fromiter(rows, dtype=np.int64, count=sum(counts))
        source = np.fromiter(map(_SOURCE, packets), dtype=np.int64, count=len(packets))
        sent = np.fromiter(map(_SENT_EPOCH, packets), dtype=np.int64, count=len(packets))
        if not kind.delayed:
            current = sent[entry] == epoch
            receiver, entry = receiver[current], entry[current]
        used = np.zeros(len(packets), dtype=bool)
        used[entry] = True
        if used.all():
            decoded = payloads(kind.model, packets)
        else:  # only the packets some pair uses are read
            decoded = [None] * len(packets)
            wanted = np.flatnonzero(used).tolist()
            for e, m in zip(
                wanted, payloads(kind.model, [packets[e] for e in wanted]), strict=True
            ):
                decoded[e] = m
        agent = _agents_named(decoded)
        owner = source[entry] if kind.owner == "source" else receiver
        valid = (agent[entry] == owner) & (agent[entry] >= 0)
        if not valid.all():
            for r, e in zip(receiver[~valid].tolist(), entry[~valid].tolist(), strict=True):
                self.service.malformed.counts[kind.link(self.run_id, r, packets[e])] += 1
            receiver, entry = receiver[valid], entry[valid]
        return Columns(receiver, entry, packets, decoded, source, sent)


class RealtimeInbox(_Receivers):
    """Realtime: what netem forwarded, by epoch, taken at the phase's deadline."""

    def __init__(
        self,
        service: Service,
        receivers: Iterable[int],
        counts: MutableMapping[str, int],
        clock: Callable[[], Clock | None],
    ) -> None:
        super().__init__(service, receivers, counts)
        self._clock = clock  # the run's, once the node has joined it
        # receiver → packet key → (epoch, packet, payload), by phase
        self.filed: dict[str, dict[int, dict[Hashable, tuple[int, DeliveredPacket, Any]]]] = {}
        self.taken: dict[str, int] = {}  # phase → the last epoch taken
        # phase → (receiver, epoch) → the senders of what is filed: whether a phase is complete
        self.senders: dict[str, dict[tuple[int, int], set[int]]] = {}
        # phase → epoch → (receiver, sender) whose packet was used: a later copy is no miss
        self.used: dict[str, dict[int, set[tuple[int, int]]]] = {}

    @property
    def clock(self) -> Clock:
        clock = self._clock()
        if clock is None:
            raise RuntimeError("a realtime inbox before the run's clock (join first)")
        return clock

    def route(self, msg: Incoming) -> None:
        for delivery, table, ids in self._deliveries(msg):
            self._file(delivery, [table[i] for i in ids], msg.arrived_ns)

    def _file(self, delivery: Any, packets: list[Any], arrived_ns: int) -> None:
        phase, r = delivery.phase, delivery.receiver
        kind = KINDS[phase]
        box = self.filed.setdefault(phase, {}).setdefault(r, {})
        senders = self.senders.setdefault(phase, {})
        taken = self.taken.get(phase, -1)
        for p, payload in self._decode(kind, r, packets):
            epoch = kind.epoch(p, payload)
            if epoch > taken:
                box[kind.key(p, payload)] = (epoch, p, payload)
                senders.setdefault((r, epoch), set()).add(p.source)
            elif not (kind.copies and self._copy(phase, r, p, epoch, arrived_ns)):
                # late, or stamped in time but queued after the deadline's take (scheduling)
                self._count(kind.late)
                silent = bool(getattr(payload, "robot_silent", False))  # states, reports
                self._count(cause(self.clock, phase, epoch, payload.stamp_ns, arrived_ns, silent))

    def _copy(self, phase: str, r: int, p: DeliveredPacket, epoch: int, arrived_ns: int) -> bool:
        """Whether a packet of an epoch taken is a copy of one used, in time."""
        in_time = arrived_ns <= self.clock.at(epoch, PHASES[phase][1])
        return in_time and (r, p.source) in self.used.get(phase, {}).get(epoch, ())

    def _count(self, name: str | None, n: int = 1) -> None:
        if name is not None:
            self.counts[name] += n

    def _complete(self, phase: str, epoch: int, expect: int) -> bool:
        senders = self.senders.get(phase, {})
        return all(len(senders.get((r, epoch), ())) >= expect for r in self.receivers)

    def take(self, phase: str, epoch: int, expect: int | None = None, early: str = "") -> Take:
        complete = None if expect is None else partial(self._complete, phase, epoch, expect)
        ended_early = yield Wait(epoch, PHASES[phase][1], complete)
        if early:
            self.counts[early] += ended_early
        kind = KINDS[phase]
        boxes = self.filed.setdefault(phase, {})
        got: Inputs = {}
        fresh: set[tuple[int, int]] = set()
        for r in self.receivers:
            box = boxes.get(r, {})
            got[r] = [(p, m) for e, p, m in box.values() if e <= epoch]
            # a sender ahead of this process: its next epoch's packets wait for it
            boxes[r] = {q: v for q, v in box.items() if v[0] > epoch}
            fresh |= {(r, p.source) for p, m in got[r] if kind.epoch(p, m) == epoch}
            self._count(kind.taken, n := sum(kind.epoch(p, m) == epoch for p, m in got[r]))
            self.counts["in_time"] += n
        self.taken[phase] = epoch
        senders = self.senders.get(phase, {})
        self.senders[phase] = {q: v for q, v in senders.items() if q[1] > epoch}
        if kind.copies:
            used = self.used.setdefault(phase, {})
            used[epoch] = fresh
            used.pop(epoch - USED_KEPT, None)
        return got

    def take_columns(
        self, phase: str, epoch: int, expect: int | None = None, early: str = ""
    ) -> Generator[Wait, bool, Columns]:
        return Columns.of((yield from self.take(phase, epoch, expect, early)))


_TOP_ID = 2**62  # an agent id past it (Python ints have no bound) names no agent of ours
_SOURCE, _SENT_EPOCH, _AGENT = attrgetter("source"), attrgetter("sent_epoch"), attrgetter("agent")
_DELIVERY, _TABLE, _ROWS = itemgetter(0), itemgetter(1), itemgetter(2)  # of a Filed
_FIRST = itemgetter(0)
_RECEIVER = attrgetter("receiver")  # of a delivery
_PHASE_EPOCH, _WHERE = attrgetter("phase", "epoch"), attrgetter("receiver", "phase", "epoch")


def _agents_named(payloads: list[Any]) -> Ids:
    """(e,) the agent each decoded payload names, as :func:`_named`: at once where every one
    was decoded and names an int64."""
    if None not in payloads:
        try:
            agent = np.fromiter(map(_AGENT, payloads), dtype=np.int64, count=len(payloads))
        except OverflowError:  # an id past int64: one by one
            pass
        else:
            agent[(agent < 0) | (agent >= _TOP_ID)] = -1
            return agent
    return np.array([_named(m) for m in payloads], dtype=np.int64)


def _named(payload: Any) -> int:
    """The agent a decoded payload names, or −1 (none decoded, or an id past any agent's)."""
    if payload is None or not 0 <= payload.agent < _TOP_ID:
        return -1
    return int(payload.agent)
