"""Unplanned faults through the command a user types (issue 20 item 2): ``formation run`` as a
subprocess, a process of it killed by PID mid-run from outside.

The PIDs come from the run's ``pids.json`` and the kill lands once agent 1's state of
``KILL_AT`` is seen (:mod:`testkit.run_watch`). ``formation run`` itself is ended by
PID in a ``finally``; the ``runs_dir`` fixture fails the test if a process of the run is left.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from formation.scenario import Scenario
from recorder import load_run, read_run
from testkit.run_watch import KillAtEpoch, KillOnSpawn, end_process, read_pids, wait_for_run

from .conftest import pid_alive, run_pids

pytestmark = pytest.mark.integration
FORMATION = Path(sys.executable).with_name("formation")  # the installed command
EPOCHS = 300
KILL_AT = 40  # agent 1's state of this epoch seen: the kill lands mid-run
AGENTS = [f"agent-{i}" for i in range(1, 6)]


@contextmanager
def formation_run(scenario: Path, runs_dir: Path, *args: str) -> Iterator[subprocess.Popen[str]]:
    """``formation run SCENARIO --runs-dir RUNS_DIR ARGS``, ended by PID on the way out."""
    out = runs_dir.parent
    with (out / "stdout.txt").open("w") as stdout, (out / "stderr.txt").open("w") as stderr:
        proc = subprocess.Popen(
            [str(FORMATION), "run", str(scenario), "--runs-dir", str(runs_dir), *args],
            stdout=stdout, stderr=stderr, text=True,
            env={k: v for k, v in os.environ.items() if k != "COLUMNS"},
        )  # fmt: skip
        try:
            yield proc
        finally:
            end_process(proc)


def run_with_kill(
    scenario: Path, runs_dir: Path, names: list[str], *args: str
) -> tuple[int, str, str, dict[str, int], Path]:
    """Run, kill ``names`` at ``KILL_AT``; exit code, stdout, stderr, PIDs killed, run folder."""
    kill = KillAtEpoch(names, KILL_AT)
    try:
        with formation_run(scenario, runs_dir, *args) as proc:
            run_dir = wait_for_run(runs_dir, proc)
            kill.start(run_dir)
            code = proc.wait(240)
    finally:
        kill.close()
    assert kill.killed, "the run ended before the kill"
    out = runs_dir.parent
    return (
        code,
        (out / "stdout.txt").read_text(),
        (out / "stderr.txt").read_text(),
        kill.killed,
        run_dir,
    )


def test_formation_run_names_the_agent_killed_and_the_epoch_it_was_lost(
    paper_path: Path, runs_dir: Path
) -> None:
    code, out, err, killed, _ = run_with_kill(
        paper_path, runs_dir, ["agent-3"], "--epochs", str(EPOCHS), "--no-record"
    )
    assert code == 0, err
    lost = re.search(
        rf"estimate: agent-3 \(pid {killed['agent-3']}\) lost at epoch (\d+): killed by SIGKILL \(exit code -9, "
        r"(\d+) packets dropped on its links, (\d+) states its receivers missed\)\n",
        out,
    )
    assert lost, out
    assert KILL_AT - 5 <= int(lost[1]) <= KILL_AT + 5  # its last state came near agent 1's
    # from the epoch it was lost to the last (states x[0] .. x[EPOCHS]), on each of its out-links
    receivers = int((Scenario.from_file(paper_path).directed_links[:, 0] == 3).sum())
    assert int(lost[3]) == (EPOCHS + 1 - int(lost[1])) * receivers > 0
    assert "restarted" not in out
    assert "Traceback" not in err
    assert not any(pid_alive(p) for p in run_pids(runs_dir))


def test_formation_run_restart_on_failure_brings_the_agent_back(
    paper_path: Path, runs_dir: Path
) -> None:
    code, out, err, killed, run_dir = run_with_kill(
        paper_path, runs_dir, ["agent-3"], "--epochs", str(EPOCHS), "--restart", "on-failure",
        "--no-record",
    )  # fmt: skip
    assert code == 0, err
    again = read_pids(run_dir)["agent-3.1"]  # the new process, as the launcher named it
    back = re.search(
        rf"agent-3 \(pid {killed['agent-3']}\) lost at epoch (\d+): .*, restarted as pid "
        rf"{again}, back from epoch (\d+)\n",
        out,
    )
    assert back, out
    assert int(back[1]) <= int(back[2]) < EPOCHS  # back before netem gave up on it: no gap
    assert not any(pid_alive(p) for p in run_pids(runs_dir))


def test_formation_run_restart_on_failure_brings_back_an_agent_killed_before_the_start(
    paper_path: Path, runs_dir: Path
) -> None:
    with (
        KillOnSpawn(runs_dir, "agent-3") as kill,
        formation_run(
            paper_path, runs_dir, "--epochs", str(EPOCHS), "--restart", "on-failure", "--no-record"
        ) as proc,
    ):
        code = proc.wait(240)
    out, err = (
        (runs_dir.parent / "stdout.txt").read_text(),
        (runs_dir.parent / "stderr.txt").read_text(),
    )
    assert code == 0, err
    (run_dir,) = runs_dir.glob("*/pids.json")
    again = read_pids(run_dir.parent)["agent-3.1"]
    assert re.search(
        rf"agent-3 \(pid {kill.killed}\) lost before the start: killed by SIGKILL \(exit code -9, .*\), restarted "
        rf"as pid {again}, back from epoch 0\n",
        out,
    ), out
    assert not any(pid_alive(p) for p in run_pids(runs_dir))


def test_formation_run_with_every_agent_killed_fails_saying_so(
    paper_path: Path, runs_dir: Path
) -> None:
    code, out, err, killed, _ = run_with_kill(
        paper_path, runs_dir, AGENTS, "--epochs", str(EPOCHS), "--no-record"
    )
    assert sorted(killed) == AGENTS
    assert code == 1, err
    gone = re.search(
        r"formation run: error: every agent is gone \(([^)]*)\); the run cannot go on", err
    )
    assert gone, err
    assert sorted(gone[1].split(", ")) == AGENTS
    assert "Traceback" not in err and "summary" not in out
    assert not any(pid_alive(p) for p in run_pids(runs_dir))


@pytest.mark.parametrize("name", ["netem", "router"])
def test_formation_run_with_netem_or_the_router_killed_fails_naming_it_and_keeps_the_recording(
    paper_path: Path, runs_dir: Path, name: str
) -> None:
    code, _, err, killed, run_dir = run_with_kill(
        paper_path, runs_dir, [name], "--epochs", "100000"
    )
    what = "the Zenoh router" if name == "router" else "netem"
    assert code == 1, err
    assert f"formation run: error: {what} (pid {killed[name]}) exited with code -9; " in err
    assert "Traceback" not in err
    assert not any(pid_alive(p) for p in run_pids(runs_dir)), "nothing is left running"
    mcap = run_dir / "run.mcap"
    recover = subprocess.run([str(FORMATION), "recover", str(mcap)], capture_output=True, text=True,
                             timeout=120)  # fmt: skip
    assert recover.returncode == 0, recover.stderr
    recovered = mcap.with_name("run-recovered.mcap")
    assert f"{recovered}: kept " in recover.stdout
    run = read_run(recovered)
    seen = np.isfinite(run.positions).all(axis=2)  # (E + 1, n)
    assert seen[: KILL_AT - 5].all(), "every agent's states up to the kill are in the recording"
    frames = load_run(recovered).tables()
    assert len(frames["states"]) >= 5 * (KILL_AT - 5)
