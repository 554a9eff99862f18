"""A run that ended early (every agent gone) still gets its report and its summary, from what
its recorder wrote before it stopped: a cut recording is recovered first."""

from __future__ import annotations

import io
import json
from pathlib import Path

from rich.console import Console

from formation.scenario import Scenario
from recorder import read_run
from testbed.cli.run import ended_summary
from testbed.sim.simulate import simulate
from testkit.synthetic import write_synthetic


def test_a_cut_recording_is_recovered_reported_and_summarised(
    paper: Scenario, tmp_path: Path
) -> None:
    scenario = paper.with_overrides(epochs=12)
    run_dir = tmp_path / "run"
    mcap = run_dir / "run.mcap"
    write_synthetic(mcap, simulate(scenario, "hold"))
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) * 2 // 3])  # the recorder stopped mid-file
    out = io.StringIO()
    ended_summary("hold", run_dir, Console(file=out, width=300))
    (summary,) = json.loads((run_dir / "summary.json").read_text())
    kept = read_run(run_dir / "run-recovered.mcap")
    assert 0 < summary["epochs"] == len(kept.positions) - 1 < scenario.epochs
    lines = out.getvalue().splitlines()
    assert lines[0] == f"report: {run_dir / 'report.md'}"
    assert lines[1] == (
        f"hold: the run ended early, after {summary['epochs']} epochs: final formation error "
        f"{summary['final_formation_error_m']:.4g} m, shape {summary['final_shape_error_m']:.4g} "
        "m (from the recording)"
    )


def test_an_unreadable_recording_is_said_in_one_line(tmp_path: Path) -> None:
    (tmp_path / "run.mcap").write_bytes(b"not an mcap file")
    out = io.StringIO()
    ended_summary("hold", tmp_path, Console(file=out, width=300))
    assert out.getvalue().startswith("hold: no summary: the recording cannot be read (")
