"""The simulator with capacity queues: a batch drops what each seed alone drops."""

from __future__ import annotations

import numpy as np
import pytest

from formation.scenario import Scenario
from testbed.sim.batch import BatchError, plan_batch, run_batch
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


def test_what_the_simulator_does_not_queue_yet_is_refused(paper: Scenario) -> None:
    events = with_capacity(paper).with_overrides(
        events=[{"epoch": 5, "agent": 4, "action": "leave"}]
    )
    with pytest.raises(BatchError, match=r"member 0 .*network\.capacity with team events"):
        plan_batch(events, [1])


def test_a_delayed_packet_the_queue_drops_never_lands(paper: Scenario) -> None:
    delay = [{"model": "delay", "epochs": 1}]
    base = with_capacity(paper, formation_default=delay)
    plan = plan_batch(base, [1])
    free = plan_batch(with_capacity(paper, formation_default=delay, capacity=[]), [1])
    landed = sum(len(f) for f, _ in plan.late.values())
    assert 0 < landed < sum(len(f) for f, _ in free.late.values())  # agent 3's radio drops some
