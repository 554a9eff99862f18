"""The main job as a user runs it: ``formation run`` from the command line, files and summary."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.integration


def test_formation_run_records_reports_and_compares(paper_path: Path, runs_dir: Path) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "testbed.cli", "run", str(paper_path), "--strategy", "zero,estimate",
         "--epochs", "20", "--runs-dir", str(runs_dir)],
        capture_output=True, text=True, timeout=300,
        env={k: v for k, v in os.environ.items() if k != "COLUMNS"},  # a pipe: rich assumes 80
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "formation run: summary" in proc.stdout
    runs = sorted(p for p in runs_dir.iterdir() if "-compare-" not in p.name)
    assert [p.name.split("-")[1] for p in runs] == ["estimate", "zero"]
    for run in runs:
        for name in ("run.mcap", "scenario.toml", "report.md", "errors.png", "pids.json"):
            assert (run / name).stat().st_size > 0, (run, name)
    (compare,) = [p for p in runs_dir.iterdir() if "-compare-" in p.name]
    summaries = json.loads((compare / "summary.json").read_text())
    by_strategy = {s["strategy"]: s for s in summaries}
    assert set(by_strategy) == {"zero", "estimate"}
    assert (
        by_strategy["zero"]["final_formation_error_m"]
        > 10 * by_strategy["estimate"]["final_formation_error_m"]
    )
    assert f"comparison of the 2 runs: {compare}" in proc.stderr.replace("\n", "")
    for s in summaries:  # the summary table shows every run's numbers whole, even in a pipe
        assert f" {s['final_formation_error_m']:.4g} " in proc.stdout, proc.stdout
    assert "…" not in proc.stdout, proc.stdout
