"""The leader's parts bundled (lockstep): netem takes each part of a ``Bundle`` as if it came
on its agent's own key, and counts and skips a bundle or part it cannot take."""

from __future__ import annotations

from pathlib import Path

import orjson

from formation import keys
from formation.codec import attachment, now_ns
from formation.messages import AgentEstimate, Delivery
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
