"""What netem's lockstep core puts out, on the bus: deliveries on ``inbox/<receiver>/<phase>``
(a declared pool's batched on ``inbox/pool/<pool>/<phase>``), decision records on
``netem/decision``."""

from __future__ import annotations

from collections.abc import Sequence

from orjson import dumps

from formation import keys
from formation.codec import now_ns
from formation.keys import LEADER_ENDPOINT
from netem.proxy.records import (
    Record,
    decision_batch,
    decision_batch_of,
    delivery_head,
    delivery_of,
)
from netem.proxy.routes import Phase
from shell import Publisher, Service


class ZenohOutbox:
    """Publishes the lockstep core's outputs: deliveries on ``inbox/<receiver>/<phase>``,
    decision records on ``netem/decision``.

    A pool process that declared its agents (:meth:`declare_pool`) gets their deliveries
    batched: each is kept until every agent of the pool has its delivery of that phase and
    epoch, then all go as one :class:`~formation.messages.DeliveryBatch`, each distinct
    packet in it once (most go to several of the pool's agents). A pool's agents live and die together (one
    process; scenario events need one process per agent), so its receivers close an epoch
    together; whatever is kept longer (a pool that died mid-epoch) goes out at the node's
    next flush (:meth:`flush_pools`).
    """

    def __init__(self, service: Service) -> None:
        self.service = service
        self._inboxes: dict[tuple[Phase, int], _Inbox] = {}  # (phase, receiver) → its inbox
        self._decision_key = keys.netem_decision(service.run_id)
        self._header = service.header_format()
        self.pool_of: dict[int, int] = {}  # receiver → its pool (the pool's first agent)
        self.pools: dict[int, frozenset[int]] = {}  # pool → its agents
        self._size: dict[int, int] = {}  # pool → its agents
        # (pool, phase) → key, publisher, the batch's fields before its deliveries
        self._pools: dict[tuple[int, Phase], tuple[str, Publisher, bytes]] = {}
        # (pool, phase, epoch) → the deliveries kept for its batch
        self._kept: dict[tuple[int, Phase, int], _PoolBatch] = {}
        self._stale: set[tuple[int, Phase, int]] = set()  # kept at the last flush

    def declare(self, agents: list[int]) -> None:
        """Declare every inbox's publisher now, before the clock starts (as
        :meth:`~shell.service.Service.declare_publishers`)."""
        for i in agents:
            for phase in ("state", "estimate"):
                self._inbox(phase, i)
        self._inbox("report", LEADER_ENDPOINT)
        self.service.publisher(self._decision_key)

    def _inbox(self, phase: Phase, receiver: int) -> _Inbox:
        inbox = self._inboxes.get((phase, receiver))
        if inbox is None:
            key = keys.inbox(self.service.run_id, receiver, phase)
            head = delivery_head(self._header, receiver, phase)
            inbox = self._inboxes[(phase, receiver)] = _Inbox(
                key, self.service.publisher(key), head
            )
            inbox.pool = self.pool_of.get(receiver)
        return inbox

    def declare_pool(self, pool: int, agents: list[int]) -> None:
        """The receivers ``agents`` are one process's, pool ``pool``: batch their deliveries
        of the agents' phases (state, estimate) from now on."""
        for i in agents:
            self.pool_of[i] = pool
            for phase in _POOLED:
                self._inbox(phase, i).pool = pool
        self.pools[pool] = self.pools.get(pool, frozenset()) | set(agents)
        self._size[pool] = len(agents)
        for phase in _POOLED:
            key = keys.inbox_pool(self.service.run_id, pool, phase)
            head = self._header + b',"kind":"delivery_batch","pool":%d,"phase":"%s"' % (
                pool,
                phase.encode(),
            )
            self._pools[(pool, phase)] = (key, self.service.publisher(key), head)

    def deliver(
        self,
        phase: Phase,
        receiver: int,
        epoch: int,
        packets: list[bytes],
        lost: list[int],
        dead: list[int],
    ) -> None:
        self._deliver(phase, receiver, epoch, now_ns(), packets, lost, dead)

    def deliver_many(
        self, phase: Phase, epoch: int, ready: list[tuple[int, list[bytes], list[int]]]
    ) -> None:
        """:meth:`deliver` of each ``(receiver, packets, lost)`` in turn, none dead, stamped
        alike."""
        stamp = now_ns()
        for receiver, packets, lost in ready:
            self._deliver(phase, receiver, epoch, stamp, packets, lost, ())

    def _deliver(
        self,
        phase: Phase,
        receiver: int,
        epoch: int,
        stamp: int,
        packets: list[bytes],
        lost: list[int],
        dead: Sequence[int],
    ) -> None:
        inbox = self._inbox(phase, receiver)
        seq = inbox.next_seq()
        pool = inbox.pool
        if pool is None:
            inbox.pub.put(delivery_of(inbox.head % (seq, epoch, stamp), packets, lost, dead))
            self.service.sent[inbox.key] += 1
            return
        at = (pool, phase, epoch)
        kept = self._kept.get(at)
        if kept is None:
            kept = self._kept[at] = _PoolBatch()
        if lost or dead:
            kept.add(delivery_of(inbox.head % (seq, epoch, stamp), (), lost, dead), packets)
        else:
            kept.add(inbox.plain % (seq, epoch, stamp), packets)
        if kept.came >= self._size[pool]:  # the pool's every agent: its batch goes
            del self._kept[at]
            self._publish(pool, phase, epoch, kept)

    def flush_pools(self) -> None:
        """Send a pool the deliveries kept for it since the last flush or before (one batch
        per phase and epoch, as far as they came): a batch under way is left to complete."""
        for at in self._stale & self._kept.keys():
            batch = self._kept[at]
            if batch.deliveries:
                self._publish(*at, batch)
                batch.clear()
        self._stale = set(self._kept)

    def _publish(self, pool: int, phase: Phase, epoch: int, batch: _PoolBatch) -> None:
        service = self.service
        key, pub, head = self._pools[(pool, phase)]
        fields = head % (service.next_seq(key), epoch, now_ns())
        pub.put(
            b'%s,"packets":[%s],"deliveries":[%s],"carried":%s}'
            % (fields, b",".join(batch.table), b",".join(batch.deliveries), dumps(batch.carried))
        )
        service.sent[key] += 1

    def records(self, phase: Phase, epoch: int, records: list[Record]) -> None:
        key = self._decision_key
        self.service.put(key, decision_batch(self.service.header(key, epoch), phase, records))

    def record_batch(self, phase: Phase, last_epoch: int, body: bytes) -> None:
        key = self._decision_key
        self.service.put(key, decision_batch_of(self.service.header(key, last_epoch), body))


_POOLED: tuple[Phase, ...] = ("state", "estimate")  # the phases a pool's deliveries are batched in
_NOTHING_ELSE = delivery_of(b"", (), (), ())  # a delivery's fields after its head: none lost


class _Inbox:
    """A receiver's key of a phase: its publisher, its delivery's fields before the packets
    (``%d`` for seq, epoch and stamp_ns; ``plain``: with nothing after them), its next seq
    and its pool (None: not batched)."""

    __slots__ = ("head", "key", "plain", "pool", "pub", "seq")

    def __init__(self, key: str, pub: Publisher, head: bytes) -> None:
        self.key, self.pub, self.head = key, pub, head
        self.plain = head + _NOTHING_ELSE
        self.seq = 0
        self.pool: int | None = None

    def next_seq(self) -> int:
        seq = self.seq
        self.seq = seq + 1
        return seq


class _PoolBatch:
    """A pool's batch of one phase and epoch as it fills: each distinct packet once in
    ``table`` (a packet is the same bytes object for all its receivers: hashed once), each
    delivery without its packets and, in ``carried``, their indices in the table."""

    __slots__ = ("came", "carried", "deliveries", "table")

    def __init__(self) -> None:
        self.table: dict[bytes, int] = {}  # packet → its index (in insertion order)
        self.deliveries: list[bytes] = []
        self.carried: list[list[int]] = []
        self.came = 0  # the pool's deliveries of the epoch, those already sent too

    def add(self, delivery: bytes, packets: list[bytes]) -> None:
        table = self.table
        add = table.setdefault  # a new packet's index is the table's length before it
        self.carried.append([add(p, len(table)) for p in packets])
        self.deliveries.append(delivery)
        self.came += 1

    def clear(self) -> None:
        """Sent: what comes next is a batch of its own (``came`` goes on counting)."""
        self.table, self.deliveries, self.carried = {}, [], []
