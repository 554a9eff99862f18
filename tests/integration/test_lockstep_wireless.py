"""Distance link models and unicycle robots in lockstep: real processes over Zenoh on 127.0.0.1
equal the simulator bit for bit (issue 19)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from analysis import summarise
from analysis.safety import axle_speeds, turn_rates
from formation.keys import LEADER_ENDPOINT
from formation.scenario import Scenario
from recorder import read_run
from testbed.runtime.launcher import launch
from testbed.sim.simulate import simulate

pytestmark = pytest.mark.integration

# A distance model on every formation link (logistic by default; range, log_distance and a
# logistic with delays on three of them) and on every control link, to an access point.
WIRELESS = {
    "formation_default": [{"model": "logistic", "d50_m": 1.4, "width_m": 0.15}],
    "links": [
        {"between": [1, 3], "models": [{"model": "range", "max_range_m": 1.95}]},
        {"between": [2, 4], "models": [{"model": "log_distance", "n": 3.0, "sigma_db": 3.0,
                                         "shadowing_correlation": 0.5,
                                         "sensitivity_dbm": -47.0}]},
        {"between": [3, 5], "models": [{"model": "logistic", "d50_m": 2.1, "width_m": 0.1},
                                       {"model": "delay", "epochs": 0, "jitter_epochs": 1}]},
    ],
    "control_default": [{"model": "logistic", "d50_m": 1.6, "width_m": 0.1}],
    "access_point": [0.0, 0.4],
}  # fmt: skip


def verdicts(outcome: Any, link_class: str) -> dict[tuple[int, int, int], bool]:
    return {
        (d.source, d.target, d.epoch): d.verdict in ("pass", "duplicate")
        for d in outcome.decisions
        if d.link_class == link_class
    }  # a delayed packet is not on time: the simulator's delivered is False there too


def expected(scenario: Scenario, sim: Any) -> dict[str, dict[tuple[int, int, int], bool]]:
    e, n = scenario.epochs, scenario.n
    return {
        "formation": {
            (int(a), int(b), k): bool(sim.delivered[k, c])
            for k in range(e)
            for c, (a, b) in enumerate(scenario.directed_links)
        },
        "report": {(i, LEADER_ENDPOINT, k): bool(sim.report_ok[k, i - 1])
                   for k in range(e) for i in range(1, n + 1)},
        "estimate": {(LEADER_ENDPOINT, i, k): bool(sim.estimate_ok[k, i - 1])
                     for k in range(e) for i in range(1, n + 1)},
    }  # fmt: skip


@pytest.mark.parametrize("dynamics", ["single", "unicycle"])
def test_distance_models_on_every_link_equal_the_simulator(
    paper: Scenario, runs_dir: Path, dynamics: str
) -> None:
    control = {"dynamics": dynamics, "controller": "displacement"}
    if dynamics == "unicycle":  # the distance law, at a gain under its bound (docs/model.md §3)
        control |= {"controller": "distance", "gain": 0.05}
    scenario = paper.with_overrides(epochs=30, network=WIRELESS, control=control)
    outcome = launch(scenario, strategy="hold", seed=5, runs_dir=runs_dir, record=False)
    sim = simulate(scenario, strategy="hold", seed=5)
    np.testing.assert_array_equal(outcome.positions, sim.positions)
    want = expected(scenario, sim)
    for link_class in ("formation", "report", "estimate"):
        assert verdicts(outcome, link_class) == want[link_class], link_class
    assert 0 < sum(not v for v in want["formation"].values()) < len(want["formation"])
    assert not all(want["report"].values()) or not all(want["estimate"].values())
    assert {d.verdict for d in outcome.decisions} >= {"pass", "drop", "delayed"}
    assert outcome.malformed == {}


def test_unicycles_with_no_loss_reach_the_shape_within_their_limits_as_recorded(
    paper: Scenario, runs_dir: Path
) -> None:
    scenario = paper.with_overrides(
        network={}, control={"dynamics": "unicycle", "gain": 0.1}, epochs=40
    )
    outcome = launch(scenario, strategy="estimate", seed=2, runs_dir=runs_dir)
    sim = simulate(scenario, strategy="estimate", seed=2)
    np.testing.assert_array_equal(outcome.positions, sim.positions)
    run = read_run(outcome.run_dir / "run.mcap")
    assert run.headings is not None and run.saturated is not None
    np.testing.assert_array_equal(run.positions, sim.positions)
    np.testing.assert_array_equal(run.headings, sim.headings)
    np.testing.assert_array_equal(run.saturated, sim.saturated)
    assert run.shape_error[-1] < 0.02 < run.shape_error[0]
    uni = scenario.control.unicycle
    speed = axle_speeds(run.positions, run.headings, uni.lookahead_m, scenario.control.period_s)
    assert np.isfinite(speed).all() and speed.max() <= uni.max_speed_m_s * (1 + 1e-12)
    assert int(run.saturated.sum()) == 0


def test_unicycles_hold_a_low_turn_limit_as_recorded_and_count_its_saturation(
    paper: Scenario, runs_dir: Path
) -> None:
    # 0.5 rad/s over a 1 s epoch is a turn the epoch's headings can show (the default 3.6
    # rad/s is more than π per epoch, which headings alone cannot tell from less).
    scenario = paper.with_overrides(
        network={},
        control={"dynamics": "unicycle", "gain": 0.1, "unicycle": {"max_turn_rad_s": 0.5}},
        epochs=20,
    )
    outcome = launch(scenario, strategy="estimate", seed=2, runs_dir=runs_dir)
    run = read_run(outcome.run_dir / "run.mcap")
    sim = simulate(scenario, strategy="estimate", seed=2)
    assert run.headings is not None and run.saturated is not None
    np.testing.assert_array_equal(run.headings, sim.headings)
    turn = np.delete(
        turn_rates(run.headings, scenario.control.period_s), scenario.reference_agent - 1, 1
    )
    assert np.isfinite(turn).all() and turn.max() <= 0.5 * (1 + 1e-12)
    assert int(run.saturated.sum()) > 0
    assert summarise(run)["safety"]["max_turn_rad_s"] == turn.max()


def test_distance_models_through_capacity_queues_equal_the_simulator(
    paper: Scenario, runs_dir: Path
) -> None:
    """The queues see what the distance models passed, which the simulator knows an epoch at a
    time: the access point's queue on every control link, and agent 2's radio."""
    network = {
        **WIRELESS,
        "capacity": [
            {"scope": "medium", "medium": "ap", "links": "control", "rate_bps": 30_000.0,
             "limit_packets": 3, "overhead_bytes": 42},
            {"scope": "radio", "agent": 2, "rate_bps": 40_000.0, "limit_packets": 2},
        ],
    }  # fmt: skip
    scenario = paper.with_overrides(epochs=30, network=network)
    outcome = launch(scenario, strategy="estimate", seed=5, runs_dir=runs_dir, record=False)
    sim = simulate(scenario, strategy="estimate", seed=5)
    np.testing.assert_array_equal(outcome.positions, sim.positions)
    want = expected(scenario, sim)
    for link_class in ("formation", "report", "estimate"):
        assert verdicts(outcome, link_class) == want[link_class], link_class
    reasons = {d.model for d in outcome.decisions if d.verdict == "drop"}
    assert {"queue_full", "logistic"} <= reasons, reasons
