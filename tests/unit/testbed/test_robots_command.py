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


def test_a_scenario_without_robots_is_a_clear_error(
    paper_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["robots", str(paper_path)]) == 1
    assert capsys.readouterr().err == (
        f"formation robots: error: {paper_path}: body.kind = 'simulated'; no agent has a robot\n"
    )
