"""A run whose leader computed covariances every K epochs says so in its report (issue 18 item 2)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from formation.scenario import Scenario, load_dict
from recorder import read_run
from recorder.reporting.report import write_report_from
from testbed.sim.simulate import simulate

ROOT = Path(__file__).resolve().parents[3]


def _paper(every: int) -> Scenario:
    data = Scenario.from_file(ROOT / "scenarios/paper.toml").model_dump(mode="json")
    data["estimator"] = {**data["estimator"], "covariance_every": every}
    data["epochs"] = 12
    return load_dict(data)


def test_the_report_says_covariances_were_computed_every_k_epochs(
    tmp_path: Path, synth: Any
) -> None:
    for every in (1, 3):
        result = simulate(_paper(every), "estimate", seed=1)
        path = tmp_path / f"k{every}" / "run.mcap"
        synth.write(path, result)
        run = read_run(path)
        has = np.isfinite(run.estimate_cov[:, 1:]).all(axis=(1, 2, 3))
        assert np.array_equal(has, np.arange(12) % every == 0)
        write_report_from([run], path.parent)
        (summary,) = json.loads((path.parent / "summary.json").read_text())  # one per run
        text = (path.parent / "report.md").read_text()
        assert summary["covariance_every"] == every
        said = "computed covariances every 3 epochs (estimator.covariance_every = 3)" in text
        assert said == (every == 3)
