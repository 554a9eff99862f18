"""Realtime, 20 agent processes at 20 Hz for 200 epochs: every packet netem decided is
accounted for, as a modelled loss, a deadline miss (by cause) or delivered in time.

Nothing here depends on how fast the machine is: the miss rate is a figure for
``bench/``, not an assertion.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from formation.deadlines import CAUSES
from formation.scenario import Scenario
from testbed.runtime.launcher import launch
from testbed.runtime.process_budget import realtime_layout

pytestmark = pytest.mark.integration
ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_twenty_agents_at_20_hz_account_for_every_packet(runs_dir: Path) -> None:
    scenario = Scenario.from_file(ROOT / "scenarios/grid20.toml").with_overrides(
        epochs=200, runtime={"mode": "realtime", "realtime_period_s": 0.05}
    )
    outcome = launch(scenario, runs_dir=runs_dir, record=False)
    s = outcome.summary()
    assert outcome.estimated_epochs == list(range(200))
    assert "nice" in s["priorities"] or "unchanged" in s["priorities"], "it says what it set"
    assert np.isfinite(outcome.positions).all()
    assert outcome.shape_error[-1] < 0.1 < outcome.shape_error[0]  # it held the formation
    misses = s["deadline_misses"]
    assert set(misses["by_cause"]) == set(CAUSES)
    assert sum(misses["by_cause"].values()) == misses["total"]
    modelled = s["modelled_losses"]
    assert modelled["dropped"] == s["packets_dropped"] > 0  # grid20's links drop packets
    assert modelled["total"] == modelled["dropped"] + modelled["delayed_past_deadline"]
    assert s["delivered_in_time"] > 0
    books = (modelled["total"], misses["total"], s["delivered_in_time"], s["packets_sent"])
    assert books[0] + books[1] + books[2] == books[3], (books, s["deadline"])
    assert s["unaccounted"] == 0
    assert s["deadline_miss_rate"] == misses["total"] / s["packets_sent"]
    # agents step once their estimate is in, not at its deadline (agent/node.py)
    assert s["deadline"]["early_steps"] > 0
    assert 0.0 <= s["cpu_steal"] < 1.0  # the hypervisor's share, from /proc/stat
    print(f"realtime 20 agents @ 20 Hz, 200 epochs: {s['deadline_misses']}, {s['deadline']}")


@pytest.mark.slow
def test_formation_run_realtime_picks_and_says_a_layout_and_records_the_accounting(
    runs_dir: Path,
) -> None:
    cores = os.cpu_count() or 1
    scenario = Scenario.from_file(ROOT / "scenarios/grid20.toml")
    layout = realtime_layout(20, 0.05, cores, len(scenario.directed_links) + 40)
    proc = subprocess.run(
        [sys.executable, "-m", "testbed.cli", "run", str(ROOT / "scenarios/grid20.toml"),
         "--mode", "realtime", "--period-s", "0.05", "--epochs", "40", "--runs-dir", str(runs_dir)],
        capture_output=True, text=True, timeout=300,
        env={k: v for k, v in os.environ.items() if k != "COLUMNS"},
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    err = proc.stderr
    assert f"realtime layout: {layout.why}" in " ".join(err.split()), err
    assert "does not trust" not in err, (
        err
    )  # a receiver's several deliveries of an epoch are no conflict
    (run,) = runs_dir.iterdir()
    agents = [
        n
        for n in json.loads((run / "pids.json").read_text())["pids"]
        if n.startswith(("agent-", "pool-"))
    ]
    assert len(agents) == (layout.pools or 20)
    books = json.loads((run / "deadlines.json").read_text())
    assert books["unaccounted"] == 0
    assert "deadline misses by cause" in proc.stdout
    assert "## Realtime: modelled losses and deadline misses" in (run / "report.md").read_text()
