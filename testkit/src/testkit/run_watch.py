"""A run watched from outside, as a user's second terminal would: its PIDs and its epochs.

The launcher writes ``<runs_dir>/<run_id>/pids.json`` (the router's endpoint and every
process it started, rewritten at each start), so a test that runs ``formation run`` as a
subprocess learns the PIDs from the file, never by a process name. :class:`KillAtEpoch`
subscribes to one agent's states over Zenoh and kills processes by PID with SIGKILL once
that agent's state of a chosen epoch is seen: the kill lands mid-run however loaded the
machine is, without a fixed sleep. :class:`KillOnSpawn` kills a process by PID as soon as
``pids.json`` names it: before it can come up, so before the run starts.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import orjson
import zenoh

from formation import keys
from shell.zenoh_config import session_config
from testbed.runtime.launcher import OnStarted


def read_pids(run_dir: Path) -> dict[str, int]:
    """Name → PID of every process the launcher started in ``run_dir`` so far."""
    pids: dict[str, int] = json.loads((run_dir / "pids.json").read_text())["pids"]
    return pids


def wait_for_run(runs_dir: Path, proc: subprocess.Popen[Any], timeout_s: float = 60.0) -> Path:
    """The run folder of the ``formation run`` in ``proc``, once its ``pids.json`` is there."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for path in runs_dir.glob("*/pids.json"):
            return path.parent
        if proc.poll() is not None:
            raise AssertionError(f"formation run exited with {proc.returncode} before starting")
        time.sleep(0.02)
    raise AssertionError(f"no pids.json in {runs_dir} after {timeout_s:g} s")


class KillAtEpoch:
    """Kills ``names``' processes by PID once agent ``watch``'s state of ``epoch`` is seen:
    the launcher's (``pids.json``), or those of ``pids`` (a process the test started)."""

    def __init__(
        self, names: list[str], epoch: int, watch: int = 1, pids: dict[str, int] | None = None
    ) -> None:
        self.names, self.epoch, self.watch, self.pids = names, epoch, watch, pids
        self.killed: dict[str, int] = {}  # name → the PID killed
        self.done = threading.Event()
        self._session: zenoh.Session | None = None

    def start(self, run_dir: Path, run_id: str | None = None) -> None:
        """Watch the run in ``run_dir`` (its id is the folder's name unless given)."""
        run_id = run_id or run_dir.name
        endpoint = json.loads((run_dir / "pids.json").read_text())["endpoint"]
        self._session = zenoh.open(session_config("client", endpoint, None))

        def on_state(sample: zenoh.Sample) -> None:
            if self.done.is_set() or orjson.loads(sample.payload.to_bytes())["epoch"] < self.epoch:
                return
            pids = self.pids or read_pids(run_dir)
            for name in self.names:
                os.kill(pids[name], signal.SIGKILL)
                self.killed[name] = pids[name]
            self.done.set()

        self._session.declare_subscriber(keys.agent_state(run_id, self.watch), on_state)

    def hook(self, runs_dir: Path) -> OnStarted:
        """An ``on_started`` hook for :func:`testbed.runtime.launcher.launch`."""
        return lambda run_id, endpoint: self.start(runs_dir / run_id, run_id)

    def close(self) -> None:
        if self._session is not None:
            self._session.close()
            self._session = None


class KillOnSpawn:
    """Kills process ``name`` with SIGKILL once a ``pids.json`` under ``runs_dir`` names it."""

    def __init__(self, runs_dir: Path, name: str, timeout_s: float = 120.0) -> None:
        self.runs_dir, self.name, self.timeout_s = runs_dir, name, timeout_s
        self.killed: int | None = None  # the PID killed
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, daemon=True)

    def __enter__(self) -> KillOnSpawn:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()

    def _watch(self) -> None:
        deadline = time.monotonic() + self.timeout_s
        while not self._stop.is_set() and time.monotonic() < deadline:
            for path in self.runs_dir.glob("*/pids.json"):
                pid = read_pids(path.parent).get(self.name)  # written atomically
                if pid is not None:
                    os.kill(pid, signal.SIGKILL)
                    self.killed = pid
                    return
            time.sleep(0.002)


def end_process(proc: subprocess.Popen[Any]) -> None:
    """End ``proc`` by PID if it still runs: SIGTERM (it stops its children), then SIGKILL."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
