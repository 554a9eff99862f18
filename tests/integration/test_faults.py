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
from recorder import read_run
from recorder.reading.recovery import recover
from testbed.runtime.launcher import launch
from testbed.runtime.outcome import RunOutcome
from testkit.run_watch import KillAtEpoch, KillOnSpawn, read_pids

from .conftest import pid_alive, run_pids

pytestmark = pytest.mark.integration
EPOCHS = 1500  # long enough that the kill lands mid-run on a loaded machine
SHORT, KILL_AT = 300, 40  # a kill at agent 1's state of KILL_AT (testkit.run_watch)


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
    events = [json.loads(d)["event"] for _, d in outcome.supervision.team_events]
    assert "back agent 3" in events


def test_the_leader_killed_and_restarted_the_agents_fall_back_meanwhile(
    paper: Scenario, runs_dir: Path
) -> None:
    """Fallbacks only while it was down; then the fault-free run's positions, to rounding.

    Lockstep equals the simulator, so both runs are the same up to the kill. While the leader
    is down agent 2 has no estimate of agent 1 (link 1–2 is down) and falls back; once the
    estimates come again (exact for the reference agent 1), the gap ``e`` between the runs
    follows ``e[k + 1] = (I − ε L_g) e[k]`` (docs/model.md §3, ``L_g`` the Laplacian grounded
    at agent 1: the measurement noise and ``v_ref`` are the same in both runs), so it shrinks
    by at least ``ρ = max |1 − ε λ(L_g)|`` per epoch. A leader that came back with a wrong
    reference would anchor agent 2's estimate elsewhere and the gap would stay.
    """
    scenario = paper.with_overrides(epochs=SHORT)
    calm = launch(scenario, runs_dir=runs_dir, record=False)
    kill = KillAtEpoch(["leader"], KILL_AT)
    try:
        outcome = launch(scenario, runs_dir=runs_dir, record=False, on_started=kill.hook(runs_dir),
                         restart="on-failure")  # fmt: skip
    finally:
        kill.close()
    assert kill.killed, "the run ended before the kill"
    (loss,) = outcome.summary()["losses"]
    assert loss["name"] == "leader" and loss["restarted_pid"] is not None
    assert np.isfinite(outcome.positions).all()
    events = [json.loads(d) for _, d in outcome.supervision.team_events]
    back = next(e for e in events if e["event"] == "back the leader")["back"]["0"]
    down = sorted(set(range(SHORT)) - set(outcome.estimated_epochs))  # no estimate published
    assert down and down == list(range(down[0], back)), "down from the kill until netem's epoch"
    assert loss["epoch"] == down[0] and KILL_AT - 5 <= down[0] <= KILL_AT + 5
    fell = outcome.supervision.fallback_epochs  # epoch → values that fell back at it
    assert sorted(fell) == down and outcome.supervision.fallbacks == sum(fell.values())
    assert calm.supervision.fallbacks == 0 and calm.supervision.fallback_epochs == {}
    # After it: the gap to the fault-free run shrinks by rho per epoch, to rounding.
    agents = [i for i in range(scenario.n) if i != scenario.reference_agent - 1]
    grounded = np.zeros((scenario.n, scenario.n))
    for a, b in scenario.edge_array - 1:
        grounded[[a, b], [a, b]] += 1.0
        grounded[a, b] = grounded[b, a] = -1.0
    grounded = grounded[np.ix_(agents, agents)]
    eps = scenario.control.gain * scenario.control.period_s
    rho = float(np.max(np.abs(1.0 - eps * np.linalg.eigvalsh(grounded))))
    gap = np.linalg.norm(outcome.positions - calm.positions, axis=(1, 2))  # (E + 1,) [m]
    assert gap[: down[0]].max() == 0.0 and gap[back] > 0.0, "the same run until the kill"
    settled = back + 1  # the first epoch every agent steps with an estimate again
    bound = rho ** (SHORT - settled) * gap[settled] + 1e-12  # [m]
    assert gap[-1] <= bound, (gap[-1], bound, rho)
    # Formation error is 2-Lipschitz in the positions: the fault-free run's tail, to the bound.
    assert abs(outcome.formation_error[-1] - calm.formation_error[-1]) <= 2 * bound
    assert outcome.formation_error[-1] < 0.01 and outcome.shape_error[-1] < 0.01


def test_an_agent_killed_while_the_team_comes_up_is_restarted_on_failure(
    paper: Scenario, runs_dir: Path
) -> None:
    """Killed as soon as its PID is known, so before the start; it takes part from epoch 0."""
    with KillOnSpawn(runs_dir, "agent-3") as kill:
        outcome = launch(paper.with_overrides(epochs=SHORT), runs_dir=runs_dir,
                         restart="on-failure")  # fmt: skip
    assert kill.killed is not None, "the run started before the kill"
    (loss,) = outcome.summary()["losses"]
    assert loss["name"] == "agent-3" and loss["pid"] == kill.killed
    assert loss["code"] == -signal.SIGKILL and loss["after_start_s"] < 0, "lost before the start"
    assert loss["restarted_pid"] == read_pids(outcome.run_dir)["agent-3.1"]
    assert loss["epoch"] == 0 and loss["back_from_epoch"] == 0 and loss["back_after_s"] > 0
    assert np.isfinite(outcome.positions).all(), "every agent at every epoch, agent 3 too"
    recorded = read_run(outcome.run_dir / "run.mcap")
    assert np.isfinite(recorded.positions).all()
    assert not any(pid_alive(p) for p in run_pids(runs_dir))


def test_an_agent_killed_while_the_team_comes_up_ends_the_run_naming_it_without_restart(
    paper: Scenario, runs_dir: Path
) -> None:
    with KillOnSpawn(runs_dir, "agent-3") as kill, pytest.raises(RuntimeFailure) as err:
        launch(paper.with_overrides(epochs=SHORT), runs_dir=runs_dir, record=False)
    assert kill.killed is not None
    (log,) = runs_dir.glob("*/logs/agent-3.log")
    assert str(err.value).startswith(
        f"agent-3 (pid {kill.killed}) exited with code -9 before the run started "
        f"(--restart on-failure starts it again); its log is {log}"
    )
    assert not any(pid_alive(p) for p in run_pids(runs_dir))


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
    recovered = recover(mcap)  # and it can be read back (formation recover, then any reader)
    run = read_run(recovered.target)
    assert recovered.messages > 0 and np.isfinite(run.positions[:2]).all()
