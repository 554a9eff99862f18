"""The leader's one loop on the in-memory bus, in lockstep: each epoch's report delivery
from netem is estimated once, in order, the agents' parts go as one bundle an epoch, and the
loop ends after the run's last epoch."""

from __future__ import annotations

import threading
from pathlib import Path

from formation import keys
from formation.messages import AgentEstimate, Bundle, Delivery, LeaderEstimate
from formation.scenario import Scenario
from leader.node import LeaderNode
from shell import Lockstep, MemoryBus, Sample, Service

ROOT = Path(__file__).resolve().parents[3]
RUN = "leader-loop"


def test_the_lockstep_loop_estimates_each_delivered_epoch_once() -> None:
    scenario = Scenario.from_file(ROOT / "scenarios/paper.toml").with_overrides(epochs=4)
    bus = MemoryBus()
    netem = Service(bus, RUN, "netem", 0)
    netem.announce()
    svc = Service(bus, RUN, "leader", 0, start_timeout_s=5)
    node = LeaderNode(svc, scenario)
    estimates: list[LeaderEstimate] = []

    def on_estimate(sample: Sample) -> None:
        estimates.append(LeaderEstimate.model_validate_json(sample.payload.to_bytes()))

    bus.declare_subscriber(keys.leader_estimate_out(RUN), on_estimate)
    bundles: list[Bundle] = []
    bus.declare_subscriber(
        keys.leader_estimates(RUN),
        lambda s: bundles.append(Bundle.model_validate_json(s.payload.to_bytes())),
    )
    key = keys.inbox(RUN, keys.LEADER_ENDPOINT, "report")

    def deliver(epoch: int) -> None:
        lost = range(1, scenario.n + 1)  # every report lost: the estimate still goes out
        msg = Delivery(**netem.header(key, epoch), receiver=keys.LEADER_ENDPOINT, phase="report",
                       packets=[], lost=list(lost))  # fmt: skip
        netem.publish(key, msg)

    deliver(0)  # before the start: queued, taken once the loop runs
    codes: list[int] = []
    thread = threading.Thread(target=lambda: codes.append(node.run(Lockstep(watch_s=0.01))))
    thread.start()
    netem.declare_start()
    try:
        deliver(2)  # ahead: kept until epoch 1 is estimated
        deliver(1)
        deliver(1)  # a copy of one already used: ignored
        deliver(3)
    finally:
        thread.join(10)
    assert codes == [0] and node.epoch == scenario.epochs
    assert [e.epoch for e in estimates] == [0, 1, 2, 3]
    assert all(e.reports_received == 0 for e in estimates)
    assert bus.puts[keys.leader_estimate_for(RUN, 1)] == 0  # lockstep: in the bundle
    assert [b.epoch for b in bundles] == [0, 1, 2, 3]
    for b in bundles:  # each agent's part, once an epoch, as it would go on its own key
        assert (b.sender, b.phase) == ("leader", "estimate")
        parts = [(p, AgentEstimate.model_validate_json(p.message)) for p in b.parts]
        assert [p.agent for p, _ in parts] == list(range(1, scenario.n + 1))
        assert all((m.agent, m.epoch, m.seq) == (p.agent, b.epoch, p.seq) for p, m in parts)
    assert dict(svc.malformed.counts) == {}
