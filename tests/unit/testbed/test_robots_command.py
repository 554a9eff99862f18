"""``formation robots SCENARIO`` prints where each robot starts, as the agents check it."""

from __future__ import annotations

from pathlib import Path

import pytest

from formation.scenario import Scenario
from testbed.cli import main


def test_it_prints_each_robot_s_start_in_its_frame(
    paper: Scenario, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scenario = paper.with_overrides(body={"kind": "ros2", "agents": [2, 3], "scale": 0.5})
    path = tmp_path / "robots.toml"
    path.write_text(scenario.to_toml())
    assert main(["robots", str(path)]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if "/cmd_vel" in line]
    x0 = scenario.initial_positions() * 0.5
    assert len(rows) == 2
    for row, i in zip(rows, (2, 3), strict=True):
        cells = [c.strip() for c in row.strip("│ ").split("│")]
        assert cells == [str(i), repr(float(x0[i - 1, 0])), repr(float(x0[i - 1, 1])),
                         f"/robot{i}/pose", f"/robot{i}/cmd_vel"]  # fmt: skip
    assert "within 0.5 m" in out


def test_a_robot_in_its_own_odometry_frame_is_told_its_start_there(
    paper: Scenario, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    odom = {"agent": 3, "frame_id": "odom3", "offset_m": [1.0, 2.0], "rotation_rad": 0.5}
    scenario = paper.with_overrides(body={"kind": "ros2", "agents": [2, 3], "transforms": [odom]})
    path = tmp_path / "robots.toml"
    path.write_text(scenario.to_toml())
    assert main(["robots", str(path)]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if "/cmd_vel" in line]
    cells = [[c.strip() for c in row.strip("│ ").split("│")] for row in rows]
    x0 = scenario.initial_positions()
    assert cells[0][:4] == ["2", "world", repr(float(x0[1, 0])), repr(float(x0[1, 1]))]
    assert cells[1][:2] == ["3", "odom3"]
    transform = scenario.body.transform_of(3)
    assert transform is not None
    back, _ = transform.to_world([float(cells[1][2]), float(cells[1][3])], 0.0)
    assert back == pytest.approx(x0[2], abs=1e-12)  # where the scenario starts it


def test_a_scenario_without_robots_is_a_clear_error(
    paper_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["robots", str(paper_path)]) == 1
    assert capsys.readouterr().err == (
        f"formation robots: error: {paper_path}: body.kind = 'simulated'; no agent has a robot\n"
    )
