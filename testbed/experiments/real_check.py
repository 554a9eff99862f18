"""One real-process run of an experiment's cell, compared with the batch simulator's positions."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from formation.scenario import Scenario
from recorder import read_run
from testbed.runtime.launcher import launch
from testbed.sim.batch import plan_batch, run_batch


def real_run_row(
    scenario: Scenario, strategy: str, seed: int, runs_dir: Path, record: bool, row: dict[str, Any]
) -> dict[str, Any]:
    """``row`` with the run's ``max_diff`` (live positions against the simulator's), and with
    ``record`` the recording's ``recorded_diff`` and path; ``match`` only when both are 0.
    A failed launch is reported in the row, not raised: the experiment goes on."""
    sim = run_batch(plan_batch(scenario, [seed]), strategy, detail=False).positions[:, 0]
    row = {**row, "recorded_diff": "-", "recording": "-"}
    try:
        o = launch(scenario, strategy=strategy, seed=seed, runs_dir=runs_dir, record=record)
    except Exception as exc:  # a failed launch is reported, not fatal to the experiment
        return {**row, "max_diff": f"launch failed: {type(exc).__name__}", "match": "no"}
    diff = float(np.max(np.abs(o.positions - sim)))
    ok = diff == 0.0
    if record:
        rec = read_run(o.run_dir / "run.mcap")
        rdiff = float(np.max(np.abs(rec.positions - sim)))
        ok = ok and rdiff == 0.0
        row.update(recorded_diff=f"{rdiff:.1e}", recording=f"`{o.run_dir / 'run.mcap'}`")
    return {**row, "max_diff": f"{diff:.1e}", "match": "yes" if ok else "no"}


__all__ = ["real_run_row"]
