"""The phase inbox's two forms (shell.inbox): lockstep takes netem's delivery of a phase;
realtime takes what came by the deadline, remembers what it used (a copy in time is no
miss) and counts a late packet by its cause."""

from __future__ import annotations

import time
from collections import Counter

from formation import keys
from formation.deadlines import CAUSES
from formation.messages import (
    AgentEstimate,
    CoordinationState,
    DeliveredPacket,
    Delivery,
    DeliveryBatch,
)
from formation.realtime import ESTIMATE_DEADLINE, Clock
from shell import Incoming, Lockstep, MemoryBus, Realtime, Service
from shell.inbox import Inputs, Take

RUN = "inbox"
KEY = keys.inbox(RUN, 1, "estimate")


def _services() -> tuple[Service, Service]:
    bus = MemoryBus()
    return Service(bus, RUN, "netem", 0), Service(bus, RUN, "agent", 1)


def _delivery(netem: Service, epoch: int, arrived_ns: int = 0, receiver: int = 1) -> Incoming:
    est = AgentEstimate(**netem.header(keys.leader_estimate_for(RUN, receiver), epoch),
                        agent=receiver, neighbours=[2], positions=[[1.0, 2.0]],
                        v_ref=[0.0, 0.0])  # fmt: skip
    packet = DeliveredPacket(source=0, seq=epoch, sent_epoch=epoch, message=est.model_dump_json())
    msg = Delivery(
        **netem.header(KEY, epoch), receiver=receiver, phase="estimate", packets=[packet], lost=[]
    )
    return Incoming(KEY, msg.model_dump_json().encode(), None, arrived_ns)


def _finish(take: Take, early: bool = False) -> Inputs:
    """The inputs a take returns once its wait has ended (``early``: before the deadline)."""
    try:
        take.send(early)
    except StopIteration as stop:
        return stop.value  # type: ignore[no-any-return]
    raise AssertionError("a take waits once")


def test_lockstep_a_phase_is_complete_once_its_delivery_is_in() -> None:
    netem, svc = _services()
    counts: Counter[str] = Counter()
    inbox = Lockstep().inbox(svc, [1], counts)
    take = inbox.take("estimate", 0)
    wait = next(take)
    assert wait.epoch == 0 and wait.at == ESTIMATE_DEADLINE and not wait.complete()
    inbox.route(_delivery(netem, 0))
    assert wait.complete()
    got = _finish(take)
    assert [est.epoch for _, est in got[1]] == [0]
    assert counts == Counter()  # lockstep keeps no deadline counts


def test_realtime_counts_a_late_packet_by_cause_and_not_a_copy_of_one_used() -> None:
    netem, svc = _services()
    timing = Realtime(period_s=1.0)
    timing.clock = Clock(time.time_ns() - 10 * 10**9, 10**9)  # epoch 0 is ten periods ago
    counts: Counter[str] = Counter()
    inbox = timing.inbox(svc, [1], counts)
    in_time = timing.clock.at(0, ESTIMATE_DEADLINE) - 1
    inbox.route(_delivery(netem, 0, in_time))
    take = inbox.take("estimate", 0, expect=1, early="early_steps")
    wait = next(take)
    assert wait.complete is not None and wait.complete()  # the one sender's estimate is in
    got = _finish(take, early=True)
    assert [est.epoch for _, est in got[1]] == [0]
    assert counts["in_time"] == counts["estimates"] == counts["early_steps"] == 1
    inbox.route(_delivery(netem, 0, in_time))  # a copy of the one used, in time: no miss
    assert counts["late_estimates"] == 0
    inbox.route(_delivery(netem, 0, time.time_ns()))  # after the deadline: a miss
    assert counts["late_estimates"] == 1
    assert sum(counts[c] for c in CAUSES) == 1


def _batch(
    netem: Service,
    pool: int,
    receivers: list[int],
    phase: str = "estimate",
    carried: list[list[int]] | None = None,
) -> bytes:
    """A pool's batch of estimate deliveries of epoch 0, each packet in its table (``phase``:
    the batch's own; ``carried``: the deliveries' indices, if not the table's in order)."""
    alone = [
        Delivery.model_validate_json(_delivery(netem, 0, receiver=r).payload) for r in receivers
    ]
    table = [p for d in alone for p in d.packets]
    return _batch_of(netem, pool, phase, table, alone, carried or [[i] for i in range(len(alone))])


def _batch_of(
    netem: Service,
    pool: int,
    phase: str,
    table: list[DeliveredPacket],
    alone: list[Delivery],
    carried: list[list[int]],
) -> bytes:
    deliveries = [d.model_copy(update={"packets": []}) for d in alone]
    return DeliveryBatch(**netem.header(keys.inbox_pool(RUN, pool, phase), 0), pool=pool,
                         phase=phase, packets=table, deliveries=deliveries,
                         carried=carried).model_dump_json().encode()  # fmt: skip


def test_lockstep_files_each_delivery_of_a_pools_batch() -> None:
    netem, svc = _services()
    inbox = Lockstep().inbox(svc, [1, 2], Counter())
    take = inbox.take("estimate", 0)
    wait = next(take)
    key = keys.inbox_pool(RUN, 1, "estimate")
    inbox.route(Incoming(key, _batch(netem, 1, [1, 2]), None, 0))
    assert wait.complete()
    got = _finish(take)
    assert {r: [est.agent for _, est in got[r]] for r in got} == {1: [1], 2: [2]}
    assert not svc.malformed.counts


def test_a_forged_or_malformed_batch_is_counted_and_skipped() -> None:
    netem, svc = _services()
    inbox = Lockstep().inbox(svc, [1, 2], Counter())
    take = inbox.take("estimate", 0)
    wait = next(take)
    key = keys.inbox_pool(RUN, 1, "estimate")
    inbox.route(Incoming(key, b'{"kind": "delivery_batch"', None, 0))  # not JSON
    inbox.route(Incoming(key, _batch(netem, 5, [1, 2]), None, 0))  # another pool's
    inbox.route(Incoming(key, _batch(netem, 1, [1, 2], "state"), None, 0))  # another phase's
    assert svc.malformed.counts[key] == 3 and not inbox.deliveries  # nothing filed
    inbox.route(Incoming(key, _batch(netem, 1, [1, 7]), None, 0))  # 7 is not this pool's
    assert svc.malformed.counts[key] == 4 and not wait.complete()
    inbox.route(Incoming(key, _batch(netem, 1, [2]), None, 0))
    assert wait.complete()


def test_a_packet_a_batch_carries_once_is_each_receivers_and_decoded_once() -> None:
    netem, svc = _services()
    inbox = Lockstep().inbox(svc, [1, 2, 3], Counter())
    take = inbox.take("state", 0)
    wait = next(take)
    state = CoordinationState(**netem.header(keys.agent_state(RUN, 4), 0), agent=4,
                              position=[0.0, 1.0], velocity=[0.0, 0.0])  # fmt: skip
    good = DeliveredPacket(source=4, seq=0, sent_epoch=0, message=state.model_dump_json())
    bad = DeliveredPacket(source=5, seq=0, sent_epoch=0, message='{"kind": "agent_state"}')
    alone = [
        Delivery(
            **netem.header(keys.inbox(RUN, r, "state"), 0),
            receiver=r,
            phase="state",
            packets=[],
            lost=[],
        )
        for r in (1, 2, 3)
    ]
    key = keys.inbox_pool(RUN, 1, "state")
    batch = _batch_of(netem, 1, "state", [good, bad], alone, [[0, 1], [0], [1, 0]])
    inbox.route(Incoming(key, batch, None, 0))
    assert wait.complete()
    got = {r: list(inputs) for r, inputs in _finish(take).items()}
    assert {r: [m.agent for _, m in got[r]] for r in got} == {1: [4], 2: [4], 3: [4]}
    assert got[1][0][1] is got[2][0][1] is got[3][0][1]  # one decoding for the three
    # the malformed one counted on each link that carried it, as if it came alone
    assert svc.malformed.counts == Counter(
        {keys.link_state(RUN, 5, 1): 1, keys.link_state(RUN, 5, 3): 1}
    )


def test_a_batch_whose_columns_or_indices_do_not_fit_its_table_is_counted_and_skipped() -> None:
    netem, svc = _services()
    inbox = Lockstep().inbox(svc, [1, 2], Counter())
    take = inbox.take("estimate", 0)
    wait = next(take)
    key = keys.inbox_pool(RUN, 1, "estimate")
    inbox.route(Incoming(key, _batch(netem, 1, [1, 2], carried=[[0]]), None, 0))  # unequal
    assert svc.malformed.counts[key] == 1 and not inbox.deliveries  # nothing filed
    inbox.route(Incoming(key, _batch(netem, 1, [1, 2], carried=[[0], [2]]), None, 0))
    inbox.route(Incoming(key, _batch(netem, 1, [1, 2], carried=[[0], [-1]]), None, 0))
    assert svc.malformed.counts[key] == 3  # an index past the table, a negative one
    assert not wait.complete()  # 1's delivery is in; 2's never was whole
    alone = Delivery.model_validate_json(_delivery(netem, 0, receiver=2).payload)
    own = DeliveryBatch.model_validate_json(_batch(netem, 1, [2])).model_copy(
        update={"deliveries": [alone]}  # its packet in the table and its own too
    )
    inbox.route(Incoming(key, own.model_dump_json().encode(), None, 0))
    assert svc.malformed.counts[key] == 4 and not wait.complete()
    inbox.route(Incoming(key, _batch(netem, 1, [2]), None, 0))
    assert wait.complete()
    got = _finish(take)
    assert {r: [est.agent for _, est in got[r]] for r in got} == {1: [1], 2: [2]}


def test_columns_hold_each_valid_pair_in_delivery_order_and_each_packet_once() -> None:
    netem, svc = _services()
    inbox = Lockstep().inbox(svc, [1, 2, 3], Counter())
    take = inbox.take_columns("state", 0)
    wait = next(take)
    state = CoordinationState(**netem.header(keys.agent_state(RUN, 4), 0), agent=4,
                              position=[0.0, 1.0])  # fmt: skip
    good = DeliveredPacket(source=4, seq=0, sent_epoch=0, message=state.model_dump_json())
    bad = DeliveredPacket(source=5, seq=0, sent_epoch=0, message='{"kind": "agent_state"}')
    forged = DeliveredPacket(source=6, seq=0, sent_epoch=0, message=state.model_dump_json())
    alone = [
        Delivery(
            **netem.header(keys.inbox(RUN, r, "state"), 0),
            receiver=r,
            phase="state",
            packets=[],
            lost=[],
        )
        for r in (1, 2, 3)
    ]
    key = keys.inbox_pool(RUN, 1, "state")
    carried = [[0, 1], [2, 0], [1, 0]]
    inbox.route(Incoming(key, _batch_of(netem, 1, "state", [good, bad, forged], alone, carried), None, 0))  # fmt: skip
    assert wait.complete()
    columns = _finish(take)  # type: ignore[arg-type]
    assert columns.receiver.tolist() == [1, 2, 3] and columns.entry.tolist() == [0, 0, 0]
    assert columns.source.tolist() == [4, 5, 6] and columns.sent_epoch.tolist() == [0, 0, 0]
    assert columns.payloads[0].agent == 4  # decoded once for the three
    # the malformed and the forged one (agent 4's state from 6) counted on each link's key
    assert svc.malformed.counts == Counter(
        {
            keys.link_state(RUN, 5, 1): 1,
            keys.link_state(RUN, 5, 3): 1,
            keys.link_state(RUN, 6, 2): 1,
        }
    )


def test_columns_of_an_estimate_leave_out_another_epochs_and_another_agents_part() -> None:
    netem, svc = _services()
    inbox = Lockstep().inbox(svc, [1, 2], Counter())
    take = inbox.take_columns("estimate", 1)
    next(take)
    old = Delivery.model_validate_json(_delivery(netem, 0, receiver=1).payload)
    now = Delivery.model_validate_json(_delivery(netem, 1, receiver=2).payload)
    other = Delivery.model_validate_json(_delivery(netem, 1, receiver=1).payload)
    table = [old.packets[0], now.packets[0], other.packets[0]]
    alone = [d.model_copy(update={"epoch": 1}) for d in (old, now)]
    key = keys.inbox_pool(RUN, 1, "estimate")
    # receiver 1 gets epoch 0's estimate (not an input of epoch 1) and agent 1's part is 2's
    batch = _batch_of(netem, 1, "estimate", table, alone, [[0], [1, 2]])
    inbox.route(Incoming(key, batch, None, 0))
    columns = _finish(take)  # type: ignore[arg-type]
    assert columns.receiver.tolist() == [2] and columns.entry.tolist() == [1]
    assert svc.malformed.counts == Counter({keys.link_estimate(RUN, 2): 1})


def test_columns_of_deliveries_that_came_alone_number_their_packets_across_them() -> None:
    netem, svc = _services()
    inbox = Lockstep().inbox(svc, [1, 2], Counter())
    take = inbox.take_columns("estimate", 0)
    wait = next(take)
    for r in (2, 1):  # each on its own key, in any order
        inbox.route(
            Incoming(keys.inbox(RUN, r, "estimate"), _delivery(netem, 0, 0, r).payload, None)
        )
    assert wait.complete()
    columns = _finish(take)  # type: ignore[arg-type]
    assert columns.receiver.tolist() == [1, 2] and columns.entry.tolist() == [0, 1]
    assert [columns.payloads[e].agent for e in columns.entry.tolist()] == [1, 2]


def test_columns_count_a_state_naming_an_agent_past_any_int64_and_keep_the_others() -> None:
    netem, svc = _services()
    inbox = Lockstep().inbox(svc, [1], Counter())
    take = inbox.take_columns("state", 0)
    next(take)
    header = netem.header(keys.agent_state(RUN, 4), 0)
    states = [  # 2**70 is read by the model: past what msgspec reads
        CoordinationState(**header, agent=agent, position=[0.0, 1.0]).model_dump_json()
        for agent in (4, 2**70)
    ]
    packets = [DeliveredPacket(source=j, seq=0, sent_epoch=0, message=m) for j, m in zip((4, 5), states, strict=True)]  # fmt: skip
    alone = [Delivery(**netem.header(keys.inbox(RUN, 1, "state"), 0), receiver=1, phase="state",
                      packets=[], lost=[])]  # fmt: skip
    key = keys.inbox_pool(RUN, 1, "state")
    inbox.route(Incoming(key, _batch_of(netem, 1, "state", packets, alone, [[0, 1]]), None, 0))
    columns = _finish(take)  # type: ignore[arg-type]
    assert columns.receiver.tolist() == [1] and columns.entry.tolist() == [0]
    assert svc.malformed.counts == Counter({keys.link_state(RUN, 5, 1): 1})
