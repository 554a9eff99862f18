"""The simulator with capacity queues: a batch drops what each seed alone drops."""

from __future__ import annotations

import numpy as np

from formation.scenario import Scenario
from testbed.sim.batch import plan_batch, run_batch
from testbed.sim.simulate import simulate


def with_capacity(paper: Scenario, **network: object) -> Scenario:
    net = paper.network.model_dump(by_alias=True)
    net["formation_default"] = [{"model": "bernoulli", "p_loss": 0.2}]
    net["capacity"] = [
        {"scope": "medium", "medium": "ap", "links": "control", "rate_bps": 25_000.0},
        {"scope": "radio", "agent": 3, "rate_bps": 20_000.0, "limit_packets": 2},
    ]
    net.update(network)
    return paper.with_overrides(network=net, epochs=20)


def test_a_batch_with_capacity_equals_each_seed_alone(paper: Scenario) -> None:
    scenario = with_capacity(paper)
    batch = run_batch(plan_batch(scenario, [1, 2, 3]), "estimate")
    for b, seed in enumerate([1, 2, 3]):
        alone = simulate(scenario, strategy="estimate", seed=seed)
        np.testing.assert_array_equal(batch.positions[:, b], alone.positions)
        np.testing.assert_array_equal(batch.report_ok[:, b], alone.report_ok)  # type: ignore[index]
    free = run_batch(plan_batch(with_capacity(paper, capacity=[]), [1]), "estimate")
    assert batch.report_ok[:, 0].sum() < free.report_ok[:, 0].sum()  # type: ignore[index]
    assert batch.delivered[:, 0].sum() < free.delivered[:, 0].sum()


def test_links_that_decide_by_length_pass_their_packets_through_the_queues(
    paper: Scenario,
) -> None:
    """A range every link is within decides epoch by epoch what no model would: the queues,
    fed an epoch at a time, then drop exactly what the plan's queues drop."""
    everywhere = [{"model": "range", "max_range_m": 50.0}]
    ranged = with_capacity(
        paper, formation_default=everywhere, control_default=everywhere, access_point=[0.0, 0.0]
    )
    plain = with_capacity(paper, formation_default=[])
    assert plan_batch(ranged, [1, 2]).ranged and not plan_batch(plain, [1, 2]).ranged
    got = run_batch(plan_batch(ranged, [1, 2]), "estimate")
    want = run_batch(plan_batch(plain, [1, 2]), "estimate")
    np.testing.assert_array_equal(got.positions, want.positions)
    np.testing.assert_array_equal(got.delivered, want.delivered)
    np.testing.assert_array_equal(got.report_ok, want.report_ok)  # type: ignore[arg-type]
    free = run_batch(
        plan_batch(with_capacity(paper, formation_default=[], capacity=[]), [1, 2]), "estimate"
    )
    assert got.report_ok.sum() < free.report_ok.sum()  # type: ignore[union-attr]


def test_an_agent_out_of_the_team_sends_nothing_through_the_queues(paper: Scenario) -> None:
    # agent 3 out from epoch 5: its radio (2 places, 20 kbit/s) then has nothing to drop
    out = with_capacity(paper).with_overrides(events=[{"epoch": 5, "agent": 3, "action": "leave"}])
    plan = plan_batch(out, [1])
    rows = [r for r, (a, _) in enumerate(paper.directed_links.tolist()) if a == 3]
    free = plan_batch(with_capacity(paper, capacity=[]).with_overrides(events=out.events), [1])
    assert (plan.on_time[:5, 0, rows] != free.on_time[:5, 0, rows]).any()  # the radio drops
    np.testing.assert_array_equal(plan.on_time[5:, 0, rows], free.on_time[5:, 0, rows])


def test_a_delayed_packet_the_queue_drops_never_lands(paper: Scenario) -> None:
    delay = [{"model": "delay", "epochs": 1}]
    base = with_capacity(paper, formation_default=delay)
    plan = plan_batch(base, [1])
    free = plan_batch(with_capacity(paper, formation_default=delay, capacity=[]), [1])
    landed = sum(len(f) for f, _ in plan.late.values())
    assert 0 < landed < sum(len(f) for f, _ in free.late.values())  # agent 3's radio drops some
