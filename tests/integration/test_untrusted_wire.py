"""Malformed and forged payloads on every kind of key during a live run (issue 20, item 3).

An independent Zenoh client puts :func:`testkit.forgeries.forgeries` on the run's keys
while ``formation run`` is in the middle of a lockstep run. The run completes with exit 0,
``report.md`` is written, and the report's summary counts each forgery on its channel; its
numbers are those of the same run without them, and ``load_run``'s DataFrames agree with it. ``formation report`` and ``formation info``
on that file exit 0 as well.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh

from analysis import error_statistics
from formation import keys
from formation.scenario import Scenario
from recorder import load_run
from shell.zenoh_config import session_config
from testkit.forgeries import forgeries

pytestmark = pytest.mark.integration
EPOCHS = 200
INJECT_AFTER = 20  # epochs: the forgeries' epoch (7) is then long past for every service


def _inject(
    runs_dir: Path, scenario: Scenario, done: dict[str, object], run_over: threading.Event
) -> None:
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not list(runs_dir.glob("*/pids.json")):
        time.sleep(0.05)
    (pids,) = runs_dir.glob("*/pids.json")
    run_id, endpoint = pids.parent.name, json.loads(pids.read_text())["endpoint"]
    session = zenoh.open(session_config("client", endpoint, None))
    try:
        seen = threading.Event()

        def on_estimate(sample: zenoh.Sample) -> None:
            if json.loads(sample.payload.to_bytes())["epoch"] >= INJECT_AFTER:
                seen.set()

        sub = session.declare_subscriber(keys.leader_estimate_out(run_id), on_estimate)
        assert seen.wait(120), "the run never reached the epoch to inject at"
        sub.undeclare()
        bad = forgeries(run_id, scenario)
        for key, payload in bad:  # BLOCK: put's default drops when the link is busy
            session.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)
        done["run_id"], done["count"], done["keys"] = run_id, len(bad), [k for k, _ in bad]
        # Open until the run is over: puts just before a close can be lost (10 of 24 were,
        # under load), and the test counts every forgery in the recording.
        run_over.wait(300)
    finally:
        session.close()


def test_forged_payloads_on_every_key_of_a_live_run(paper_path: Path, runs_dir: Path) -> None:
    scenario = Scenario.from_file(paper_path).with_overrides(epochs=EPOCHS)
    done: dict[str, object] = {}
    run_over = threading.Event()
    injector = threading.Thread(
        target=_inject, args=(runs_dir, scenario, done, run_over), daemon=True
    )
    injector.start()
    proc = subprocess.run(
        [sys.executable, "-m", "testbed.cli", "run", str(paper_path), "--epochs", str(EPOCHS),
         "--runs-dir", str(runs_dir)],
        capture_output=True, text=True, timeout=300,
        env={k: v for k, v in os.environ.items() if k != "COLUMNS"},
    )  # fmt: skip
    run_over.set()
    injector.join(10)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    assert done.get("count"), "the forgeries were never sent"
    run_dir = runs_dir / str(done["run_id"])
    assert (run_dir / "report.md").stat().st_size > 0
    (summary,) = json.loads((run_dir / "summary.json").read_text())
    skipped = summary["skipped"]
    assert skipped["total"] == done["count"], skipped
    expected: dict[str, int] = {}
    for key in done["keys"]:  # type: ignore[attr-defined]
        expected[key] = expected.get(key, 0) + 1
    assert {k: sum(v.values()) for k, v in skipped["by_channel"].items()} == expected
    assert summary["epochs_with_states"] == EPOCHS + 1
    assert summary["peak_formation_error_m"] < 1.0  # no spike from the state claiming agent 2
    assert summary["recorded_metrics_max_gap_m"] == 0.0
    assert summary["drops"] == {"1->2": EPOCHS - 1, "2->1": EPOCHS - 1}  # not the forged drops
    assert "formation run: summary" in proc.stdout and "skipped" in proc.stdout
    assert f"the report skipped {done['count']} recorded messages" in " ".join(proc.stderr.split())
    mcap = run_dir / "run.mcap"
    run = load_run(mcap)  # the DataFrames of a real run agree with its summary.json
    lost = run.decisions[(run.decisions.link_class == "formation") & ~run.decisions.on_time]
    assert lost.groupby("link").size().to_dict() == summary["drops"]
    assert run.metrics["formation_error_m"].iloc[-1] == summary["final_formation_error_m"]
    assert run.skipped.as_json() == skipped
    errors = run.substitutions[["error_x", "error_y"]].to_numpy()
    assert len(errors) == summary["substitutions"]
    assert error_statistics(errors)[2] == pytest.approx(summary["substitution_cov_trace_m2"])
    for cmd in (["report", str(mcap)], ["info", str(mcap), "--json"]):
        again = subprocess.run(
            [sys.executable, "-m", "testbed.cli", *cmd], capture_output=True, text=True, timeout=120
        )
        assert again.returncode == 0, again.stderr
    assert json.loads(again.stdout.splitlines()[-1])["skipped"]["total"] == done["count"]
