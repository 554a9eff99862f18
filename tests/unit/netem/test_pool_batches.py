"""A pool's deliveries batched by netem (netem.outbox): a pool declares its agents on
``netem/pool``; their deliveries of a phase and epoch then go as one message on
``inbox/pool/<p>/<phase>`` once every agent of the pool has its own, each as it would have
gone alone; the other receivers keep their own keys; what a pool that stopped mid-epoch
left kept goes out at the second flush."""

from __future__ import annotations

from pathlib import Path

from formation import keys
from formation.codec import attachment, encode, now_ns
from formation.messages import CoordinationState, Delivery, DeliveryBatch
from formation.scenario import Scenario
from netem.node import NetemNode
from netem.proxy.records import packet_json
from shell import MemoryBus, Sample, Service

ROOT = Path(__file__).resolve().parents[3]
RUN = "netem-pool"


def _state(i: int, k: int) -> tuple[str, bytes, bytes]:
    msg = CoordinationState(run_id=RUN, sender=f"agent/{i}", seq=k, epoch=k, stamp_ns=now_ns(),
                            agent=i, position=[float(i), float(k)])  # fmt: skip
    return keys.agent_state(RUN, i), encode(msg), attachment(k, k, i)


class _Rig:
    """netem on the in-memory bus, paper's five agents without loss, and what it sends."""

    def __init__(self) -> None:
        scenario = Scenario.from_file(ROOT / "scenarios/paper.toml").with_overrides(
            epochs=10, network={}
        )
        self.senders = scenario.in_neighbours
        bus = MemoryBus()
        self.netem = Service(bus, RUN, "netem", 0, start_timeout_s=5)
        self.pool = Service(bus, RUN, "pool", 1, start_timeout_s=5)
        self.alone: list[Delivery] = []
        self.batches: list[DeliveryBatch] = []
        bus.declare_subscriber(keys.inbox(RUN, "*", "state"), self._alone)
        bus.declare_subscriber(keys.inbox_pool(RUN, "*", "state"), self._batch)
        self.node = NetemNode(self.netem, scenario, seed=1, wait_for_recorder=False)
        with self.node.lock:
            self.node.running = True

    def _alone(self, sample: Sample) -> None:
        self.alone.append(Delivery.model_validate_json(sample.payload.to_bytes()))

    def _batch(self, sample: Sample) -> None:
        self.batches.append(DeliveryBatch.model_validate_json(sample.payload.to_bytes()))

    def declare(self, pool: int, agents: list[int]) -> dict[str, object] | None:
        return self.pool.ask(keys.netem_pool(RUN), {"pool": pool, "agents": agents})

    def close(self) -> None:
        self.pool.close()
        self.netem.close()


def test_a_pools_deliveries_go_as_one_batch_once_each_agent_has_its_own() -> None:
    rig = _Rig()
    try:
        assert rig.declare(1, [1, 2, 3]) == {"batched": True}
        for i in (1, 2, 3, 4, 5):
            rig.node.handle_packet(*_state(i, 0))
    finally:
        rig.close()
    assert sorted(d.receiver for d in rig.alone) == [4, 5]  # not pooled: on their own keys
    (batch,) = rig.batches
    assert (batch.pool, batch.phase, batch.epoch, batch.sender) == (1, "state", 0, "netem")
    assert sorted(d.receiver for d in batch.deliveries) == [1, 2, 3]
    for d, ids in zip(batch.deliveries, batch.carried, strict=True):
        # each as it would go alone: its own key's seq, every packet (from the batch's table)
        assert (d.phase, d.epoch, d.seq, d.lost, d.dead, d.packets) == ("state", 0, 0, [], [], [])
        assert sorted(batch.packets[i].source for i in ids) == rig.senders[d.receiver - 1]
    # each distinct packet once, though several of the pool's agents get it
    in_pool = {s for r in (1, 2, 3) for s in rig.senders[r - 1]}
    assert sorted(p.source for p in batch.packets) == sorted(in_pool)
    assert sum(len(ids) for ids in batch.carried) > len(in_pool)


def test_what_a_stopped_pool_left_goes_out_at_the_second_flush() -> None:
    rig = _Rig()
    try:
        rig.declare(1, [1, 2, 3])
        for i in (1, 2, 4, 5):  # agent 3's state never comes: receivers waiting for it stay open
            rig.node.handle_packet(*_state(i, 0))
        closed = {r for r in (1, 2, 3) if 3 not in rig.senders[r - 1]}
        assert closed and not rig.batches  # kept for the pool's other receivers
        rig.node.flush_all()
        assert not rig.batches  # a batch may be under way: left one flush
        rig.node.flush_all()
    finally:
        rig.close()
    (batch,) = rig.batches
    assert {d.receiver for d in batch.deliveries} == closed


def test_a_declaration_netem_cannot_take_is_refused_and_counted() -> None:
    rig = _Rig()
    try:
        assert rig.declare(1, [1, 2]) is not None
        for pool, agents in ((2, [2, 3]), (3, [3, 9]), (4, [3, 4]), (4, [])):
            # an agent of another pool, an unknown agent, a pool not named by its first agent
            assert rig.declare(pool, agents) is None, (pool, agents)
    finally:
        rig.close()
    assert rig.netem.malformed.counts[keys.netem_pool(RUN)] == 4


def test_deliveries_handed_over_at_once_go_as_those_handed_one_by_one() -> None:
    rig = _Rig()
    shared, own = (packet_json(s, 0, 0, 1, b"{}") for s in (1, 2))
    # 4 is not pooled: its delivery goes on its own key between the pool's
    ready = [(1, [shared], []), (4, [own], []), (2, [shared, own], [3]), (3, [], [])]
    try:
        rig.declare(1, [1, 2, 3])
        for receiver, packets, lost in ready:
            rig.node.outbox.deliver("state", receiver, 0, packets, lost, [])
        rig.node.outbox.deliver_many("state", 1, ready)
        rig.node.outbox.deliver_many("state", 2, ready)
    finally:
        rig.close()
    # each delivery its own key's seq: the first on each key 0, then 1, 2
    assert [(d.receiver, d.epoch, d.seq) for d in rig.alone] == [(4, k, k) for k in range(3)]
    assert [[d.seq for d in b.deliveries] for b in rig.batches] == [[k] * 3 for k in range(3)]
    one_by_one, at_once, again = (
        b.model_dump(exclude={"seq", "epoch", "stamp_ns"}) for b in rig.batches
    )
    for d in [*one_by_one["deliveries"], *at_once["deliveries"], *again["deliveries"]]:
        d.pop("stamp_ns"), d.pop("epoch"), d.pop("seq")
    assert at_once == one_by_one == again
    assert at_once["carried"] == [[0], [0, 1], []]  # the shared packet once in the table
