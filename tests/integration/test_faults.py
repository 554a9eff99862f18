"""Unplanned faults through the real processes (issue 20 item 2): a process killed mid-run.

An agent or the leader killed is a loss, not the end; with ``restart="on-failure"`` it
comes back and rejoins from netem's ``netem/rejoin``. netem or the router killed ends the
run with an error naming it. Every process is ended by PID (the ``runs_dir`` fixture
fails the test if one is left).
"""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from formation.errors import RuntimeFailure
from formation.scenario import Scenario
from testbed.runtime.launcher import RunOutcome, launch

from .conftest import pid_alive, run_pids

pytestmark = pytest.mark.integration
EPOCHS = 1500  # long enough that the kill lands mid-run on a loaded machine


def kill_later(runs_dir: Path, name: str, after_s: float = 0.5) -> tuple[Any, list[int]]:
    """An ``on_started`` hook killing process ``name`` with SIGKILL ``after_s`` into the run."""
    killed: list[int] = []

    def hook(run_id: str, endpoint: str) -> None:
        pid = json.loads((runs_dir / run_id / "pids.json").read_text())["pids"][name]

        def kill() -> None:
            time.sleep(after_s)
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)

        threading.Thread(target=kill, daemon=True).start()

    return hook, killed


def run_with_kill(paper: Scenario, runs_dir: Path, name: str, restart: str) -> RunOutcome:
    hook, killed = kill_later(runs_dir, name)
    outcome = launch(paper.with_overrides(epochs=EPOCHS), runs_dir=runs_dir, record=False,
                     on_started=hook, restart=restart)  # type: ignore[arg-type]  # fmt: skip
    assert killed, "the run ended before the kill"
    return outcome


def test_a_killed_agent_is_a_loss_and_the_run_goes_on(paper: Scenario, runs_dir: Path) -> None:
    outcome = run_with_kill(paper, runs_dir, "agent-3", "no")
    (loss,) = outcome.summary()["losses"]
    assert loss["name"] == "agent-3" and loss["code"] == -signal.SIGKILL
    assert 0 < loss["epoch"] < EPOCHS and loss["restarted_pid"] is None
    seen = np.isfinite(outcome.positions).all(axis=2)  # (E + 1, n)
    assert seen[:, [0, 1, 3, 4]].all(), "every other agent's states cover every epoch"
    assert seen[: loss["epoch"], 2].all() and not seen[loss["epoch"] :, 2].any()
    assert [tuple(span) for span in outcome.summary()["team"]["3"]] == [(0, loss["epoch"] - 1)]
    assert not any(pid_alive(p) for p in run_pids(runs_dir))


def test_a_killed_agent_restarted_on_failure_rejoins_where_its_body_was(
    paper: Scenario, runs_dir: Path
) -> None:
    outcome = run_with_kill(paper, runs_dir, "agent-3", "on-failure")
    (loss,) = outcome.summary()["losses"]
    assert loss["restarted_pid"] is not None and loss["back_from_epoch"] is not None
    x3 = outcome.positions[:, 2]
    seen = np.isfinite(x3).all(axis=1)
    back = loss["back_from_epoch"]
    assert seen[back:].all(), "its recorded states run to the last epoch"
    before = int(np.flatnonzero(seen[:back])[-1])
    assert np.array_equal(x3[back], x3[before]), "its first position back is the last before"
    assert np.isfinite(outcome.positions[:, [0, 1, 3, 4]]).all()
    events = [json.loads(d)["event"] for _, d in outcome.extra["team_events"]]
    assert "back agent 3" in events


def test_the_leader_killed_and_restarted_the_agents_fall_back_meanwhile(
    paper: Scenario, runs_dir: Path
) -> None:
    outcome = run_with_kill(paper, runs_dir, "leader", "on-failure")
    (loss,) = outcome.summary()["losses"]
    assert loss["name"] == "leader" and loss["restarted_pid"] is not None
    assert np.isfinite(outcome.positions).all()
    assert outcome.extra["fallbacks"] > 0  # paper: link 1-2 down, and no estimate to fill it
    events = [json.loads(d) for _, d in outcome.extra["team_events"]]
    back = next(e for e in events if e["event"] == "back the leader")["back"]["0"]
    estimated = set(outcome.estimated_epochs)
    assert set(range(back, EPOCHS)) <= estimated, "it estimates again from the epoch netem gave"
    assert outcome.shape_error[-1] < 0.1


@pytest.mark.parametrize("name", ["netem", "router"])
def test_netem_or_the_router_killed_ends_the_run_naming_it(
    paper: Scenario, runs_dir: Path, name: str
) -> None:
    hook, killed = kill_later(runs_dir, name)
    what = "the Zenoh router" if name == "router" else "netem"
    with pytest.raises(RuntimeFailure, match=rf"{what} \(pid \d+\) exited with code -9"):
        launch(paper.with_overrides(epochs=100000), runs_dir=runs_dir, on_started=hook)
    assert killed
    (mcap,) = runs_dir.glob("*/run.mcap")
    assert mcap.stat().st_size > 0, "the recording is kept"
    assert not any(pid_alive(p) for p in run_pids(runs_dir))
