"""An experiment cell's real-process check: equal to the batch simulator, live and recorded."""

from __future__ import annotations

from pathlib import Path

import pytest

from formation.scenario import Scenario
from testbed.experiments.real_check import real_run_row

pytestmark = pytest.mark.integration


def test_a_real_run_of_a_cell_matches_the_simulator_live_and_recorded(
    paper: Scenario, runs_dir: Path
) -> None:
    short = paper.with_overrides(epochs=15)
    row = real_run_row(short, "hold", 3, runs_dir, True, {"strategy": "hold", "seed": 3})
    assert list(row) == ["strategy", "seed", "recorded_diff", "recording", "max_diff", "match"]
    assert (row["max_diff"], row["recorded_diff"], row["match"]) == ("0.0e+00", "0.0e+00", "yes")
    assert row["recording"].endswith("run.mcap`")
