"""Safety counts in every summary and report: from the simulator and from a recording."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from analysis import safety_counts
from analysis.safety import axle_speeds
from formation.scenario import Scenario
from recorder import load_run, read_run
from recorder.reporting.report import write_report, write_report_from
from testbed.sim.simulate import simulate

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def robots() -> Scenario:
    """The paper's team as unicycles, bodies 0.5 m across, in a box agent 5 leaves."""
    return Scenario.from_file(ROOT / "scenarios" / "paper.toml").with_overrides(
        control={"dynamics": "unicycle"},
        safety={"body_diameter_m": 0.5, "bounds": {"min_m": [-1.0, -1.0], "max_m": [1.0, 1.2]}},
    )


def test_safety_counts_of_known_positions() -> None:
    s = Scenario.from_file(ROOT / "scenarios" / "paper.toml").with_overrides(
        safety={"body_diameter_m": 0.3, "bounds": {"min_m": [-2.0, -2.0], "max_m": [2.0, 2.0]}}
    )
    x = np.tile(s.offsets, (4, 1, 1))
    x[1:3, 1] = x[1:3, 0] + [0.1, 0.0]  # 2 touches 1 at epochs 1-2: one collision
    x[3, 4] = [5.0, 0.0]  # 5 leaves the box for one epoch
    x[2, 3] = np.nan  # 4 not recorded at epoch 2
    got = safety_counts(s, x)
    assert got["collisions"] == {"1-2": 1} and got["collisions_total"] == 1
    assert got["min_distance_m"] == pytest.approx(0.1)
    assert got["min_distance_per_epoch_m"][1:3] == pytest.approx([0.1, 0.1])
    assert got["time_out_of_bounds_s"] == {"1": 0.0, "2": 0.0, "3": 0.0, "4": 0.0, "5": 1.0}
    assert "saturated_steps" not in got


def test_summary_json_and_report_carry_the_safety_counts(robots: Scenario, tmp_path: Path) -> None:
    result = simulate(robots)
    write_report_from([result.record()], tmp_path)
    (summary,) = json.loads((tmp_path / "summary.json").read_text())
    safety: dict[str, Any] = summary["safety"]
    assert safety == json.loads(json.dumps(result.summary()["safety"]))
    assert len(safety["min_distance_per_epoch_m"]) == robots.epochs + 1
    assert safety["time_out_of_bounds_s"]["5"] > 0
    assert sum(safety["saturated_steps"].values()) == int(result.saturated.sum()) > 0
    assert safety["max_speed_m_s"] <= robots.control.unicycle.max_speed_m_s + 1e-12
    report = (tmp_path / "report.md").read_text()
    assert "## Safety" in report and "saturated sub-steps" in report


def test_a_recording_gives_the_simulators_safety_counts(
    robots: Scenario, tmp_path: Path, synth: Any
) -> None:
    result = simulate(robots)
    path = tmp_path / "run.mcap"
    synth.write(path, result)
    run = read_run(path)
    assert run.headings is not None and run.saturated is not None
    np.testing.assert_array_equal(run.headings, result.headings)
    np.testing.assert_array_equal(run.saturated, result.saturated)
    write_report(path, tmp_path)
    (summary,) = json.loads((tmp_path / "summary.json").read_text())
    expected = json.loads(json.dumps(result.summary()["safety"]))
    assert summary["safety"] == expected


def test_axle_speed_is_the_chord_of_the_axles_path() -> None:
    # A unicycle turning in place: its look-ahead point moves, its axle does not.
    th = np.array([[0.0], [np.pi / 2]])
    p = 0.05 * np.stack([np.cos(th), np.sin(th)], axis=-1)
    np.testing.assert_allclose(axle_speeds(p, th, 0.05, 1.0), [[0.0]], atol=1e-15)


def test_load_run_gives_a_unicycles_heading_and_saturation(
    robots: Scenario, tmp_path: Path, synth: Any
) -> None:
    result = simulate(robots)
    path = tmp_path / "run.mcap"
    synth.write(path, result)
    states = load_run(path).states
    for i in range(1, robots.n + 1):
        mine = states[states.agent == i].sort_values("epoch")
        np.testing.assert_array_equal(mine.heading.to_numpy(), result.headings[:, i - 1])
        sat = mine.saturated.to_numpy()
        np.testing.assert_array_equal(sat[1:], result.saturated[:, i - 1])  # the step into k
