"""netem's lockstep driven through its node on the in-memory bus: a sender that dies in
the middle of an epoch, after some receivers already got their delivery."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import orjson

from formation import keys
from formation.codec import attachment, encode, now_ns
from formation.messages import CoordinationState, DecisionBatch, Delivery, decision_rows
from formation.scenario import Scenario
from netem.node import NetemNode
from shell import MemoryBus, Sample, Service

ROOT = Path(__file__).resolve().parents[3]
RUN = "netem-node"


def _state(i: int, k: int) -> tuple[str, bytes, bytes]:
    msg = CoordinationState(run_id=RUN, sender=f"agent/{i}", seq=k, epoch=k, stamp_ns=now_ns(),
                            agent=i, position=[float(i), float(k)])  # fmt: skip
    return keys.agent_state(RUN, i), encode(msg), attachment(k, k, i)


def test_a_sender_dying_mid_epoch_closes_every_receiver_once() -> None:
    scenario = Scenario.from_file(ROOT / "scenarios/paper.toml").with_overrides(
        epochs=10, network={}
    )  # no loss: every link passes every packet
    bus = MemoryBus()
    service = Service(bus, RUN, "netem", 0, start_timeout_s=5)
    got: list[Delivery] = []
    records: list[DecisionBatch] = []

    def on_delivery(sample: Sample) -> None:
        got.append(Delivery.model_validate_json(sample.payload.to_bytes()))

    def on_records(sample: Sample) -> None:
        records.append(DecisionBatch.model_validate_json(sample.payload.to_bytes()))

    bus.declare_subscriber(keys.inbox(RUN, "*", "state"), on_delivery)
    bus.declare_subscriber(keys.netem_decision(RUN), on_records)
    try:
        node = NetemNode(service, scenario, seed=1, wait_for_recorder=False)
        with node.lock:
            node.running = True
        senders = scenario.in_neighbours  # paper: 5 hears 3 and 4 only
        for i in (3, 4, 1, 2):  # agent 5's packet of epoch 0 never comes
            node.handle_packet(*_state(i, 0))
        # Receiver 5 heard from all its senders (3, 4): delivered already.
        with node.lock:
            node.on_dead(5)  # 5 counts as lost
        node.flush_all()
    finally:
        service.close()
    by_receiver = Counter(d.receiver for d in got)
    assert by_receiver == dict.fromkeys(range(1, 6), 1), by_receiver  # each closed exactly once
    for d in got:
        assert d.epoch == 0
        want = [j for j in senders[d.receiver - 1] if j != 5]
        assert sorted(p.source for p in d.packets) == want
        assert d.dead == ([5] if 5 in senders[d.receiver - 1] else [])
        for p in d.packets:
            assert orjson.loads(p.message)["agent"] == p.source
    # One decision record per packet that came: every out-link of agents 1-4, exactly once.
    rec = Counter((r.source, r.target) for b in records for r in decision_rows(b) if r.epoch == 0)
    want_links = {(int(a), int(b)) for a, b in scenario.directed_links if int(a) != 5}
    assert set(rec) == want_links and set(rec.values()) == {1}
