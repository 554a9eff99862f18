"""Multi-process fixtures: every process a test starts is ended by PID, also when the test fails."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import time
from collections.abc import Iterator
from pathlib import Path

import pytest


def pid_alive(pid: int) -> bool:
    """True while ``pid`` runs (a zombie awaiting its parent counts as ended)."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("State:"):
                    return "Z" not in line
    except FileNotFoundError:
        return False
    return True


def run_pids(runs_dir: Path) -> list[int]:
    """Every PID the launcher recorded in ``runs_dir/*/pids.json``."""
    pids: list[int] = []
    for path in runs_dir.glob("*/pids.json"):
        try:
            pids.extend(json.loads(path.read_text())["pids"].values())
        except (OSError, ValueError, KeyError):
            continue  # written atomically; a failure here must not hide live processes elsewhere
    return pids


def end_pids(pids: list[int]) -> list[int]:
    """Kill what still runs, by PID; returns the PIDs that had been left running."""
    left = [p for p in pids if pid_alive(p)]
    for p in left:
        with contextlib.suppress(ProcessLookupError):
            os.kill(p, signal.SIGKILL)
    return left


@pytest.fixture
def runs_dir(tmp_path: Path) -> Iterator[Path]:
    """A runs folder; afterwards no process of any run in it may be left alive."""
    path = tmp_path / "runs"
    path.mkdir()
    yield path
    deadline = time.monotonic() + 10
    while any(pid_alive(p) for p in run_pids(path)) and time.monotonic() < deadline:
        time.sleep(0.05)
    left = end_pids(run_pids(path))
    assert not left, f"processes left running after the test: {left}"
