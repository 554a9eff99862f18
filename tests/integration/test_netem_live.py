"""``formation netem set`` changes a live run's link from the next epoch; bad changes are refused."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from formation.scenario import Scenario
from testbed.launcher import launch

pytestmark = pytest.mark.integration


def cli(runs_dir: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "testbed.cli", "netem", *args, "--runs-dir", str(runs_dir)],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip


def test_live_change_and_refusals(paper: Scenario, runs_dir: Path) -> None:
    results: dict[str, subprocess.CompletedProcess[str]] = {}

    def change(run_id: str, endpoint: str) -> None:
        results["set"] = cli(runs_dir, "set", "2->3", "bernoulli", "p_loss=1.0")
        results["unknown"] = cli(runs_dir, "set", "1->5", "down")
        results["bad_p"] = cli(runs_dir, "set", "2->3", "bernoulli", "p_loss=1.5")
        results["show"] = cli(runs_dir, "show")

    outcome = launch(
        paper.with_overrides(epochs=800), runs_dir=runs_dir, record=False, on_started=change
    )
    assert results["show"].returncode == 0 and "2->3" in results["show"].stdout
    assert results["unknown"].returncode == 1
    assert "link '1->5': no such link in the scenario" in results["unknown"].stderr
    assert results["bad_p"].returncode == 1
    assert "models.0.bernoulli.p_loss = 1.5" in results["bad_p"].stderr
    assert results["set"].returncode == 0, results["set"].stderr
    found = re.search(r"new models from epoch (\d+)", results["set"].stdout)
    assert found, results["set"].stdout
    start = int(found.group(1))
    assert 0 < start < 800
    verdicts = {d.epoch: d.verdict for d in outcome.decisions if (d.source, d.target) == (2, 3)}
    assert len(verdicts) == 800
    assert all(v == "pass" for e, v in verdicts.items() if e < start)
    assert all(
        v == "drop" for e, v in verdicts.items() if e >= start
    )  # the refused changes left it so
    assert "bernoulli p_loss=1.0" in results["show"].stdout
    assert all(d.verdict == "pass" for d in outcome.decisions if (d.source, d.target) == (3, 2))
