"""The simulator with distance link models and unicycle robots (issue 19)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from analysis import safety_counts
from analysis.safety import axle_speeds, turn_rates
from formation.keys import LEADER_ENDPOINT
from formation.scenario import Scenario
from netem.links.matrix import link_lengths
from netem.links.models import LinkModel
from testbed.sim.batch import plan_batch, run_batch
from testbed.sim.simulate import simulate

ROOT = Path(__file__).resolve().parents[3]
WIRELESS = {
    "formation_default": [{"model": "logistic", "d50_m": 1.4, "width_m": 0.15}],
    "links": [
        {"between": [1, 3], "models": [{"model": "range", "max_range_m": 1.7}]},
        {"between": [2, 4], "models": [{"model": "log_distance", "n": 3.0, "sigma_db": 3.0,
                                         "shadowing_correlation": 0.5,
                                         "sensitivity_dbm": -47.0}]},
        {"between": [3, 5], "models": [{"model": "logistic", "d50_m": 1.6, "width_m": 0.1},
                                       {"model": "delay", "epochs": 0, "jitter_epochs": 1}]},
    ],
    "control_default": [{"model": "logistic", "d50_m": 1.6, "width_m": 0.1}],
    "access_point": [0.0, 0.4],
}  # fmt: skip


@pytest.fixture(scope="module")
def paper() -> Scenario:
    return Scenario.from_file(ROOT / "scenarios" / "paper.toml")


def _netem_verdicts(s: Scenario, seed: int, x: np.ndarray) -> tuple[np.ndarray, ...]:
    """What netem's per-link models decide at the true lengths: on time, report, estimate."""
    ap = np.asarray(s.network.access_point, dtype=float)
    links = s.directed_links
    on_time = np.zeros((s.epochs, len(links)), dtype=bool)
    ctl = np.zeros((2, s.epochs, s.n), dtype=bool)
    models = [LinkModel(s.formation_link_models(int(a), int(b)), seed, int(a), int(b))
              for a, b in links]  # fmt: skip
    control = [
        [LinkModel(s.control_link_models(i, "report"), seed, i, LEADER_ENDPOINT)
         for i in range(1, s.n + 1)],
        [LinkModel(s.control_link_models(i, "estimate"), seed, LEADER_ENDPOINT, i)
         for i in range(1, s.n + 1)],
    ]  # fmt: skip
    for k in range(s.epochs):
        for c, ((a, b), m) in enumerate(zip(links, models, strict=True)):
            length = float(link_lengths(x[k, a - 1][None], x[k, b - 1][None])[0])
            d = m.decide(k, distance_m=length)
            on_time[k, c] = d.delivered and d.delay_epochs == 0
        for side, ms in enumerate(control):
            for i, m in enumerate(ms):
                length = float(link_lengths(x[k, i][None], ap[None])[0])
                d = m.decide(k, distance_m=length)
                ctl[side, k, i] = d.delivered and d.delay_epochs == 0
    return on_time, ctl[0], ctl[1]


@pytest.mark.parametrize("dynamics", ["single", "unicycle"])
def test_distance_links_decided_at_the_simulated_positions_as_netem_decides(
    paper: Scenario, dynamics: str
) -> None:
    s = paper.with_overrides(epochs=40, network=WIRELESS, control={"dynamics": dynamics})
    sim = simulate(s, strategy="hold", seed=5)
    on_time, report, estimate = _netem_verdicts(s, 5, sim.positions)
    np.testing.assert_array_equal(sim.delivered, on_time)
    np.testing.assert_array_equal(sim.report_ok, report)
    np.testing.assert_array_equal(sim.estimate_ok, estimate)
    assert 0 < (~sim.delivered).sum() < sim.delivered.size  # the lengths matter both ways
    assert (~sim.report_ok).any() or (~sim.estimate_ok).any()


def test_a_batch_member_with_distance_links_equals_its_run_alone(paper: Scenario) -> None:
    near = paper.with_overrides(epochs=30, network=WIRELESS)
    far = paper.with_overrides(
        epochs=30, network={"formation_default": [{"model": "range", "max_range_m": 1.0}]}
    )
    plain = paper.with_overrides(epochs=30)
    plan = plan_batch([plain, near, far, near], [1, 2, 2, 3])
    res = run_batch(plan, "estimate")
    for b, (s, seed) in enumerate([(plain, 1), (near, 2), (far, 2), (near, 3)]):
        alone = simulate(s, strategy="estimate", seed=seed)
        np.testing.assert_array_equal(res.positions[:, b], alone.positions)
        np.testing.assert_array_equal(res.delivered[:, b], alone.delivered)
    sub = run_batch(plan.subset([3, 1]), "estimate")
    np.testing.assert_array_equal(sub.positions[:, 0], res.positions[:, 3])


def test_unicycles_without_loss_reach_the_shape_under_their_speed_limit(paper: Scenario) -> None:
    s = paper.with_overrides(network={}, control={"dynamics": "unicycle", "gain": 0.1})
    sim = simulate(s)
    assert sim.shape_error[-1] < 0.01 < sim.shape_error[0]
    uni = s.control.unicycle
    speed = axle_speeds(sim.positions, sim.headings, uni.lookahead_m, s.control.period_s)
    assert speed.max() <= uni.max_speed_m_s * (1 + 1e-12)
    assert speed.max() > 0.5 * uni.max_speed_m_s
    assert sim.saturated.sum() == 0  # a gentle gain never asks for more than the robot can


def test_saturation_is_counted_when_the_gain_is_too_high(paper: Scenario) -> None:
    def saturated(gain: float) -> int:
        s = paper.with_overrides(network={}, control={"dynamics": "unicycle", "gain": gain})
        sim = simulate(s)
        uni = s.control.unicycle
        speed = axle_speeds(sim.positions, sim.headings, uni.lookahead_m, s.control.period_s)
        assert speed.max() <= uni.max_speed_m_s * (1 + 1e-12)  # clipped, never exceeded
        assert sim.saturated[:, s.reference_agent - 1].sum() == 0
        return int(sim.saturated.sum())

    assert saturated(0.1) == 0 < saturated(0.2) < saturated(0.3)


def test_a_low_turn_limit_is_held_and_its_saturation_counted(paper: Scenario) -> None:
    s = paper.with_overrides(
        network={},
        control={"dynamics": "unicycle", "gain": 0.1, "unicycle": {"max_turn_rad_s": 0.5}},
    )
    sim = simulate(s)
    turn = turn_rates(sim.headings, s.control.period_s)  # 0.5 rad per epoch: visible (< π)
    followers = np.delete(turn, s.reference_agent - 1, axis=1)
    assert followers.max() <= 0.5 * (1 + 1e-12)
    assert followers.max() > 0.5 * (1 - 1e-9), "turning as fast as allowed at first"
    assert sim.saturated.sum() > 0
    counts = safety_counts(s, sim.positions, sim.headings, sim.saturated)
    assert counts["max_turn_rad_s"] == followers.max() and counts["max_turn_limit_rad_s"] == 0.5
    loose = simulate(
        paper.with_overrides(network={}, control={"dynamics": "unicycle", "gain": 0.1})
    )
    assert turn_rates(loose.headings, 1.0)[:, 1:].max() > 0.5, "the limit is what held it"


def test_initial_headings_are_keyed_by_the_seed(paper: Scenario) -> None:
    s = paper.with_overrides(epochs=3, control={"dynamics": "unicycle"})
    a, b, c = simulate(s, seed=1), simulate(s, seed=1), simulate(s, seed=2)
    np.testing.assert_array_equal(a.headings, b.headings)
    assert not np.allclose(a.headings[0], c.headings[0])
    assert np.all(np.abs(a.headings) <= math.pi)
