"""Ctrl-C, a dying process, malformed payloads and bad endpoints: clear outcomes, no orphans (realtime: test_realtime_accounting)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

from formation import keys
from formation.codec import attachment
from formation.errors import RuntimeFailure
from formation.scenario import Scenario
from shell.zenoh_config import session_config
from testbed.runtime.launcher import launch
from testbed.runtime.processes import free_port

from .conftest import pid_alive, run_pids

pytestmark = pytest.mark.integration
ROOT = Path(__file__).resolve().parents[2]


def wait_for(cond, timeout_s: float, what: str) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.02)


def test_ctrl_c_stops_every_process_and_exits(paper_path: Path, runs_dir: Path) -> None:
    env = {**os.environ, "COLUMNS": "120"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "testbed.cli", "run", str(paper_path), "--epochs", "100000", "--no-record",
         "--runs-dir", str(runs_dir)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
    )  # fmt: skip
    try:
        pids_file = lambda: next(runs_dir.glob("*/pids.json"), None)  # noqa: E731
        wait_for(
            lambda: (
                pids_file() is not None and len(json.loads(pids_file().read_text())["pids"]) == 8
            ),
            60,
            "all processes",
        )
        wait_for(lambda: all(pid_alive(p) for p in run_pids(runs_dir)), 10, "processes running")
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 130, err
        assert b"interrupted" in err
        wait_for(lambda: not any(pid_alive(p) for p in run_pids(runs_dir)), 20, "children to end")
    finally:
        if proc.poll() is None:  # let the launcher end its children first; kill it only if it hangs
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def test_malformed_payloads_are_counted_and_skipped(paper: Scenario, runs_dir: Path) -> None:
    sent = threading.Event()

    def inject(run_id: str, endpoint: str) -> None:
        with zenoh.open(session_config("client", endpoint, None)) as s:
            s.put(
                keys.agent_state(run_id, 2), b"not json at all"
            )  # no attachment: netem rejects it
            # Well routed, badly formed: netem delivers it as agent 2's packet of epoch 590;
            # its receivers count it and take it as lost.
            s.put(keys.agent_state(run_id, 2), b"{oops", attachment=attachment(590, 10**6, 2))
            s.put(keys.inbox(run_id, 4, "state"), b"{broken")
            s.put(keys.inbox(run_id, keys.LEADER_ENDPOINT, "report"), b"[]")
        sent.set()

    # Long enough (a few seconds) that the injector's session is up well before the end.
    outcome = launch(
        paper.with_overrides(epochs=600), runs_dir=runs_dir, record=False, on_started=inject
    )
    assert sent.is_set()
    assert np.isfinite(outcome.positions).all()
    bad = outcome.malformed
    assert bad.get(keys.agent_state(outcome.run_id, 2), 0) >= 1  # counted by netem
    assert bad.get(keys.inbox(outcome.run_id, 4, "state"), 0) >= 1  # counted by agent 4
    receivers = [j for j, senders in enumerate(paper.in_neighbours, start=1) if 2 in senders]
    inside = [keys.link_state(outcome.run_id, 2, j) for j in receivers]
    assert sum(bad.get(k, 0) for k in inside) >= 1, bad  # counted by agent 2's receivers
    assert (
        bad.get(keys.inbox(outcome.run_id, keys.LEADER_ENDPOINT, "report"), 0) >= 1
    )  # by the leader


@pytest.mark.parametrize("service", ["agent", "leader", "netem"])
def test_unreachable_endpoint_is_a_clear_error(paper_path: Path, service: str) -> None:
    port = free_port()
    args = ["--scenario", str(paper_path), "--mode", "client", "--connect", f"tcp/127.0.0.1:{port}"]
    args += ["--connect-timeout", "1"]  # a client retries until its router answers; not for long
    if service == "agent":
        args += ["--id", "2"]
    proc = subprocess.run(
        [sys.executable, "-m", service, *args], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 1
    assert f"{service}: error: cannot open a Zenoh session (tcp/127.0.0.1:{port})" in proc.stderr


def test_unknown_agent_id_is_a_clear_error(paper_path: Path) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "agent", "--scenario", str(paper_path), "--id", "9"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert proc.returncode == 1
    assert "agent: error: --id 9: no such agent in the scenario (agents are 1..5)" in proc.stderr


def test_a_stalled_run_says_where_each_process_waits(paper: Scenario, runs_dir: Path) -> None:
    """netem frozen (SIGSTOP): the launcher gives up after the epoch timeout, and before it ends
    the processes each live one has written its threads' stacks into its log."""
    frozen: list[int] = []

    def freeze_netem(run_id: str, endpoint: str) -> None:
        pids = json.loads((runs_dir / run_id / "pids.json").read_text())["pids"]
        frozen.append(pids["netem"])
        os.kill(pids["netem"], signal.SIGSTOP)

    try:
        with pytest.raises(RuntimeFailure, match=r"no epoch finished for 2 s") as err:
            launch(paper.with_overrides(epochs=100_000), runs_dir=runs_dir, record=False,
                   on_started=freeze_netem, epoch_timeout_s=2.0)  # fmt: skip
    finally:
        for pid in frozen:  # ended by the launcher already; a leftover must not stay stopped
            if pid_alive(pid):
                os.kill(pid, signal.SIGCONT)
    (log_dir,) = runs_dir.glob("*/logs")
    assert str(log_dir) in str(err.value)
    for name in ["router", "leader", "agent-1", "agent-5"]:
        text = (log_dir / f"{name}.log").read_text()
        assert "most recent call first" in text and 'File "' in text, (name, text[-2000:])
    assert "most recent call first" not in (log_dir / "netem.log").read_text()  # it was frozen
