"""``formation netem set`` changes a live run's link from the next epoch; bad changes are refused."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from formation.scenario import Scenario
from testbed.cli.netem import ask, parse_models
from testbed.runtime.launcher import launch

pytestmark = pytest.mark.integration


def cli(runs_dir: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "testbed.cli", "netem", *args, "--runs-dir", str(runs_dir)],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip


def test_live_change_and_refusals(paper: Scenario, runs_dir: Path) -> None:
    results: dict[str, subprocess.CompletedProcess[str]] = {}
    answers: dict[str, dict[str, object]] = {}

    def change(run_id: str, endpoint: str) -> None:
        results["set"] = cli(runs_dir, "set", "2->3", "bernoulli", "p_loss=1.0")
        # Refusals through the CLI's own request code, in-process: the run must still be going.
        answers["unknown"] = ask(
            run_id, endpoint, {"op": "set", "link": "1->5", "models": [{"model": "down"}]}
        )
        answers["bad_p"] = ask(run_id, endpoint, {"op": "set", "link": "2->3",
                                                  "models": parse_models(["bernoulli", "p_loss=1.5"])})  # fmt: skip
        results["show"] = cli(runs_dir, "show")

    outcome = launch(
        paper.with_overrides(epochs=2000), runs_dir=runs_dir, record=False, on_started=change
    )
    assert results["show"].returncode == 0 and "2->3" in results["show"].stdout
    assert answers["unknown"] == {"ok": False, "error": "link '1->5': no such link in the scenario"}
    assert answers["bad_p"]["ok"] is False
    assert "models.0.p_loss = 1.5" in str(answers["bad_p"]["error"])  # no union label: found by tag
    assert results["set"].returncode == 0, results["set"].stderr
    found = re.search(r"new models from epoch (\d+)", results["set"].stdout)
    assert found, results["set"].stdout
    start = int(found.group(1))
    assert 0 < start < 2000
    verdicts = {d.epoch: d.verdict for d in outcome.decisions if (d.source, d.target) == (2, 3)}
    assert len(verdicts) == 2000
    assert all(v == "pass" for e, v in verdicts.items() if e < start)
    assert all(
        v == "drop" for e, v in verdicts.items() if e >= start
    )  # the refused changes left it so
    assert "bernoulli p_loss=1.0" in results["show"].stdout
    assert all(d.verdict == "pass" for d in outcome.decisions if (d.source, d.target) == (3, 2))


def test_a_refused_change_through_the_cli_exits_nonzero(tmp_path: Path) -> None:
    """With no run to talk to, the CLI says so and exits 1 (the refusal wording is pinned above)."""
    proc = cli(tmp_path, "set", "1->2", "bernoulli", "p_loss=0.5")
    assert proc.returncode == 1
    assert "no running run found under" in proc.stderr
