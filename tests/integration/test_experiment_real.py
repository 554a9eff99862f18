"""``formation experiment paper``'s real-process run: recorded to MCAP, equal to the simulation."""

from __future__ import annotations

from pathlib import Path

import pytest

from formation.scenario import Scenario
from testbed.experiments.paper import PaperResults, run_variants
from testbed.experiments.paper_run import SKIPPED_NOTE, representative_seed, run_real

pytestmark = pytest.mark.integration


def test_representative_seed_through_real_processes(paper: Scenario, runs_dir: Path) -> None:
    seeds = (1, 2, 3)
    result = PaperResults(paper, seeds, run_variants(paper, seeds))
    run_real(result, runs_dir.parent, record=True, strategies=("estimate",))
    row, events = result.real
    assert events["match"] == "yes", events  # the dynamic team's leave and join, as events
    assert events["real_final"] == events["sim_final"]
    assert row["seed"] == representative_seed(result.runs["failure"]["estimate"])
    assert row["match"] == "yes", row
    assert row["max_diff_text"] == "0.0e+00" and row["recorded_diff_text"] == "0.0e+00"
    assert list(runs_dir.glob("*/run.mcap"))
    text = (runs_dir.parent / "real_runs.md").read_text()
    assert "| estimate |" in text
    # Each recording read back: nothing skipped as untrusted, and the table and note say so.
    assert row["skipped"] == 0 and events["skipped"] == 0
    assert events["recorded_diff_text"] == "0.0e+00 (published states)"
    assert "| recording | skipped |" in text and SKIPPED_NOTE in text
    assert sum(line.endswith("run.mcap | 0 |") for line in text.splitlines()) == 2
