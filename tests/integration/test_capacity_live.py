"""``formation netem set ... rate``: a live run's queue changes from the next epoch, recorded."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from formation.scenario import Scenario
from testbed.cli.netem import ask, parse_models, queue_request
from testbed.runtime.launcher import launch

pytestmark = pytest.mark.integration
EPOCHS = 2500  # long enough for a CLI process to start on a loaded machine


def cli(runs_dir: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "testbed.cli", "netem", *args, "--runs-dir", str(runs_dir)],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip


def test_a_queue_changes_while_running_and_bad_changes_are_refused(
    paper: Scenario, runs_dir: Path
) -> None:
    network = paper.network.model_dump(by_alias=True)
    network["capacity"] = [
        {"scope": "medium", "medium": "ap", "links": "control", "rate_bps": 1e7}
    ]  # everything passes until the change
    scenario = paper.with_overrides(network=network, epochs=EPOCHS)
    results: dict[str, subprocess.CompletedProcess[str]] = {}
    answers: dict[str, dict[str, object]] = {}

    def change(run_id: str, endpoint: str) -> None:
        results["ap"] = cli(
            runs_dir, "set", "medium:ap", "rate", "rate_bps=8000", "limit_packets=1"
        )
        # a new queue, through the CLI's own request code, in-process: the run must still be going
        link = queue_request("2->3", parse_models(["rate", "rate_bps=1000"]))
        answers["link"] = ask(run_id, endpoint, {"op": "capacity", "queue": link})
        answers["radio"] = ask(
            run_id,
            endpoint,
            {"op": "capacity", "queue": {"scope": "radio", "agent": 4, "rate_bps": 1e4}},
        )
        answers["zero"] = ask(
            run_id,
            endpoint,
            {"op": "capacity", "queue": {"scope": "link", "link": [2, 3], "rate_bps": 0}},
        )

    outcome = launch(scenario, runs_dir=runs_dir, record=False, on_started=change)
    assert answers["radio"] == {
        "ok": False,
        "error": "radio 4: no such queue in the scenario's network.capacity",
    }
    assert answers["zero"]["ok"] is False
    assert "rate.rate_bps = 0" in str(answers["zero"]["error"])
    assert results["ap"].returncode == 0, results["ap"].stderr
    assert answers["link"]["ok"] is True and answers["link"]["links"] == 1, answers["link"]
    said = re.search(r"medium ap \(10 links\): new rate from epoch (\d+)", results["ap"].stdout)
    assert said, results["ap"].stdout
    ap_from, link_from = int(said.group(1)), int(str(answers["link"]["from_epoch"]))
    assert 0 < ap_from <= link_from < EPOCHS
    reports = [d for d in outcome.decisions if d.link_class == "report"]
    assert all(d.verdict == "pass" for d in reports if d.epoch < ap_from)
    after = [d for d in reports if d.epoch >= ap_from]
    # 8,000 bit/s and one place: one report of five gets through each epoch, the rest find it full
    assert sum(d.verdict == "pass" for d in after) == len(after) // 5
    assert {d.model for d in after if d.verdict == "drop"} == {"queue_full"}
    states = {d.epoch: d for d in outcome.decisions if (d.source, d.target) == (2, 3)}
    assert all(d.verdict == "pass" for k, d in states.items() if k < link_from)
    assert all(
        d.verdict == "drop" and d.model == "queue_late" for k, d in states.items() if k >= link_from
    )  # 300 B at 1,000 bit/s: 2.4 s, past the state deadline
