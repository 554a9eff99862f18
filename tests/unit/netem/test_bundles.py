"""Bundles (lockstep), the leader's parts and a declared pool's states and reports: netem takes each part
of a ``Bundle`` as if it came on its agent's own key, and counts and skips a bundle or part it
cannot take."""

from __future__ import annotations

from pathlib import Path

import orjson

from formation import keys
from formation.codec import attachment, now_ns
from formation.messages import (
    AgentEstimate,
    CoordinationState,
    Delivery,
    DeliveryBatch,
    TokenReport,
)
from formation.scenario import Scenario
from netem.node import NetemNode
from shell import MemoryBus, Sample, Service

ROOT = Path(__file__).resolve().parents[3]
RUN = "netem-bundle"
KEY = keys.leader_estimates(RUN)


def _bundle(epoch: int, agents: list[int], phase: str = "estimate") -> bytes:
    parts = []
    for i in agents:
        part = AgentEstimate(run_id=RUN, sender="leader", seq=epoch, epoch=epoch,
                             stamp_ns=now_ns(), agent=i, neighbours=[], positions=[],
                             v_ref=[0.0, 0.0])  # fmt: skip
        parts.append({"agent": i, "seq": epoch, "message": part.model_dump_json()})
    head = {"run_id": RUN, "sender": "leader", "seq": epoch, "epoch": epoch, "stamp_ns": 1}
    return orjson.dumps({**head, "kind": "bundle", "phase": phase, "parts": parts})


def test_each_part_of_a_bundle_goes_to_its_agent_and_a_bad_one_is_counted() -> None:
    scenario = Scenario.from_file(ROOT / "scenarios/paper.toml").with_overrides(
        epochs=10, network={}
    )
    bus = MemoryBus()
    service = Service(bus, RUN, "netem", 0, start_timeout_s=5)
    got: list[Delivery] = []

    def on_delivery(sample: Sample) -> None:
        got.append(Delivery.model_validate_json(sample.payload.to_bytes()))

    bus.declare_subscriber(keys.inbox(RUN, "*", "estimate"), on_delivery)
    try:
        node = NetemNode(service, scenario, seed=1, wait_for_recorder=False)
        with node.lock:
            node.running = True
        att = attachment(0, 0, keys.LEADER_ENDPOINT)
        node.handle_packet(KEY, b"[1, 2", att)  # not JSON
        node.handle_packet(KEY, _bundle(0, [1, 2], phase="state"), att)  # not estimates
        assert not got and service.malformed.counts[KEY] == 2
        node.handle_packet(KEY, _bundle(0, [1, 2, 9, 3, 4, 5]), att)  # 9: no such agent
    finally:
        service.close()
    assert service.malformed.counts[KEY] == 3
    assert sorted(d.receiver for d in got) == [1, 2, 3, 4, 5]
    for d in got:
        (packet,) = d.packets
        assert (d.epoch, packet.source, packet.seq) == (0, keys.LEADER_ENDPOINT, 0)
        assert AgentEstimate.model_validate_json(packet.message).agent == d.receiver


def _report(sender: str, i: int, epoch: int) -> str:
    return TokenReport(run_id=RUN, sender=sender, seq=epoch, epoch=epoch, stamp_ns=now_ns(),
                       agent=i, measurements=[]).model_dump_json()  # fmt: skip


def _reports(pool: int, epoch: int, agents: list[int]) -> bytes:
    parts = [
        {"agent": i, "seq": epoch, "message": _report(f"pool/{pool}", i, epoch)} for i in agents
    ]
    head = {"run_id": RUN, "sender": f"pool/{pool}", "seq": epoch, "epoch": epoch, "stamp_ns": 1}
    return orjson.dumps({**head, "kind": "bundle", "phase": "report", "parts": parts})


def test_a_declared_pools_reports_reach_the_leader_and_no_other_agents_parts() -> None:
    scenario = Scenario.from_file(ROOT / "scenarios/paper.toml").with_overrides(
        epochs=10, network={}
    )
    bus = MemoryBus()
    service = Service(bus, RUN, "netem", 0, start_timeout_s=5)
    pool = Service(bus, RUN, "pool", 1, start_timeout_s=5)
    got: list[Delivery] = []

    def on_delivery(sample: Sample) -> None:
        got.append(Delivery.model_validate_json(sample.payload.to_bytes()))

    bus.declare_subscriber(keys.inbox(RUN, keys.LEADER_ENDPOINT, "report"), on_delivery)
    first, second = keys.pool_bundle(RUN, 1, "report"), keys.pool_bundle(RUN, 4, "report")
    try:
        node = NetemNode(service, scenario, seed=1, wait_for_recorder=False)
        with node.lock:
            node.running = True
        assert pool.ask(keys.netem_pool(RUN), {"pool": 1, "agents": [1, 2, 3]}) is not None
        node.handle_packet(second, _reports(4, 0, [4, 5]), None)  # pool 4 never declared
        node.handle_packet(first, _reports(1, 0, [1, 2, 4, 3]), None)  # 4 is not pool 1's
        assert not got
        assert service.malformed.counts == {second: 2, first: 1}
        for i in (4, 5):  # on their own keys
            report = _report(f"agent/{i}", i, 0).encode()
            node.handle_packet(keys.agent_report(RUN, i), report, attachment(0, 0, i))
    finally:
        pool.close()
        service.close()
    (delivery,) = got
    assert sorted(p.source for p in delivery.packets) == [1, 2, 3, 4, 5]
    assert delivery.lost == [] and delivery.epoch == 0


def _state(sender: str, i: int, epoch: int) -> str:
    return CoordinationState(run_id=RUN, sender=sender, seq=epoch, epoch=epoch,
                             stamp_ns=now_ns(), agent=i, position=[float(i), 0.0],
                             substituted=[]).model_dump_json()  # fmt: skip


def _states(pool: int, epoch: int, agents: list[int]) -> bytes:
    parts = [
        {"agent": i, "seq": epoch, "message": _state(f"pool/{pool}", i, epoch)} for i in agents
    ]
    head = {"run_id": RUN, "sender": f"pool/{pool}", "seq": epoch, "epoch": epoch, "stamp_ns": 1}
    return orjson.dumps({**head, "kind": "bundle", "phase": "state", "parts": parts})


def test_a_declared_pools_states_go_on_each_agents_out_links_as_if_each_came_alone() -> None:
    scenario = Scenario.from_file(ROOT / "scenarios/paper.toml").with_overrides(
        epochs=10, network={}
    )
    bus = MemoryBus()
    service = Service(bus, RUN, "netem", 0, start_timeout_s=5)
    pool = Service(bus, RUN, "pool", 1, start_timeout_s=5)
    got: list[Delivery] = []

    def on_delivery(sample: Sample) -> None:
        got.append(Delivery.model_validate_json(sample.payload.to_bytes()))

    def on_batch(sample: Sample) -> None:
        batch = DeliveryBatch.model_validate_json(sample.payload.to_bytes())
        for d, ids in zip(batch.deliveries, batch.carried, strict=True):
            got.append(d.model_copy(update={"packets": [batch.packets[i] for i in ids]}))

    bus.declare_subscriber(keys.inbox(RUN, "*", "state"), on_delivery)
    bus.declare_subscriber(keys.inbox_pool(RUN, "*", "state"), on_batch)
    first, second = keys.pool_states(RUN, 1), keys.pool_states(RUN, 4)
    try:
        node = NetemNode(service, scenario, seed=1, wait_for_recorder=False)
        with node.lock:
            node.running = True
        assert pool.ask(keys.netem_pool(RUN), {"pool": 1, "agents": [1, 2, 3]}) is not None
        node.handle_packet(second, _states(4, 0, [4, 5]), None)  # pool 4 never declared
        node.handle_packet(first, _states(1, 0, [1, 2, 4, 3]), None)  # 4 is not pool 1's
        node.handle_packet(first, _states(1, 0, [1]).replace(b'"state"', b'"report"'), None)
        assert service.malformed.counts == {second: 2, first: 2}
        for i in (4, 5):  # on their own keys
            state = _state(f"agent/{i}", i, 0).encode()
            node.handle_packet(keys.agent_state(RUN, i), state, attachment(0, 0, i))
        in_links = {j: sorted(node.links.in_links[j]) for j in node.agents}
    finally:
        pool.close()
        service.close()
    assert sorted(d.receiver for d in got) == [1, 2, 3, 4, 5]
    for d in got:  # each receiver has each in-neighbour's state, exactly as it was sent
        assert sorted(p.source for p in d.packets) == in_links[d.receiver]
        for p in d.packets:
            sender = "pool/1" if p.source <= 3 else f"agent/{p.source}"
            state = CoordinationState.model_validate_json(p.message)
            assert (state.agent, state.sender, state.epoch) == (p.source, sender, 0)


def test_an_agent_is_lost_once_its_token_is_gone_past_the_grace_and_not_before() -> None:
    """netem looks only at agents whose token went missing, yet decides as if it looked at all:
    one back before the check is not lost, and a token lost again counts from that loss."""
    scenario = Scenario.from_file(ROOT / "scenarios/paper.toml").with_overrides(epochs=10)
    bus = MemoryBus()
    service = Service(bus, RUN, "netem", 0, start_timeout_s=5)
    try:
        node = NetemNode(service, scenario, seed=1, wait_for_recorder=False)
        tokens = {i: bus.declare_token(keys.alive(RUN, "agent", i)) for i in range(1, 6)}
        leader = bus.declare_token(keys.alive(RUN, "leader", 0))
        node._check_dead(grace_s=60)
        tokens[2].undeclare()
        node._check_dead(grace_s=60)  # 2 missing since now: within its grace
        tokens[2] = bus.declare_token(keys.alive(RUN, "agent", 2))
        node._check_dead(grace_s=60)  # back: its missing time forgotten
        tokens[2].undeclare()
        tokens[3].undeclare()
        node._check_dead(grace_s=0)
        assert node.dead == set()  # both missing from now, not from 2's first loss
        node._check_dead(grace_s=0)  # any time later is past a grace of 0
        assert node.dead == {2, 3}
        leader.undeclare()
    finally:
        service.close()
