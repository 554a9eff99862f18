"""This test process as a Zenoh peer on 127.0.0.1, and the service processes it starts.

Shared by the recorder's live and replay tests (``tests/integration/test_recorder_*.py``).
The peer listens on a free port; children connect to it in client mode, as the launcher
starts them. Readiness is a liveliness token or a queryable's reply, never a fixed sleep;
every child is ended by PID in a ``finally``.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
import zenoh

from formation.codec import encode
from formation.messages import CoordinationState
from shell import Service, session_config

HOST = "127.0.0.1"
WAIT_S = 30.0  # longest wait for any readiness [s]
EXIT_GRACE_S = 2.0  # [s] for the last messages of a process that has exited


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((HOST, 0))
        return int(s.getsockname()[1])


def child_env() -> dict[str, str]:
    env = dict(os.environ)
    return env


@contextmanager
def peer() -> Iterator[tuple[Any, str]]:
    """This test's Zenoh peer, listening on loopback; yields (session, endpoint)."""
    endpoint = f"tcp/{HOST}:{free_port()}"
    session: Any = zenoh.open(session_config("peer", None, endpoint))
    try:
        yield session, endpoint
    finally:
        session.close()


@contextmanager
def process(*args: str, log: Path) -> Iterator[subprocess.Popen[bytes]]:
    """A child process; killed by PID at the end if it is still running."""
    with open(log, "wb") as out:
        proc = subprocess.Popen(
            [sys.executable, *args], env=child_env(), stdout=out, stderr=subprocess.STDOUT
        )
        try:
            yield proc
        finally:
            if proc.poll() is None:
                os.kill(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)


def wait_for(
    condition: Callable[[], bool], proc: subprocess.Popen[bytes] | None, what: str, log: Path
) -> None:
    deadline = time.monotonic() + WAIT_S
    exited_at: float | None = None
    while not condition():
        if exited_at is None and proc is not None and proc.poll() is not None:
            exited_at = time.monotonic()  # what it sent last may still be on its way
        if exited_at is not None and time.monotonic() - exited_at > EXIT_GRACE_S:
            assert proc is not None
            pytest.fail(
                f"process exited ({proc.returncode}) while waiting for {what}:\n{log.read_text()[-3000:]}"
            )
        if time.monotonic() > deadline:
            pytest.fail(f"timed out waiting for {what}:\n{log.read_text()[-3000:]}")
        time.sleep(0.01)


@contextmanager
def token_seen(session: Any, key: str) -> Iterator[Callable[[], bool]]:
    """A condition that turns true once the liveliness token ``key`` exists (history included)."""
    seen = threading.Event()

    def on_token(sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            seen.set()

    sub = session.liveliness().declare_subscriber(key, on_token, history=True)
    try:
        yield seen.is_set
    finally:
        sub.undeclare()


def state(run_id: str, i: int, k: int, x: list[float]) -> bytes:
    return encode(
        CoordinationState(
            run_id=run_id,
            sender=f"agent/{i}",
            seq=k,
            epoch=k,
            stamp_ns=time.monotonic_ns(),
            agent=i,
            position=x,
        )
    )


@contextmanager
def peer_service(run_id: str, role: str, ident: int) -> Iterator[Service]:
    """A service of this process, a peer on loopback (the signals stay pytest's)."""
    conf = session_config("peer", None, "tcp/127.0.0.1:0")
    svc = Service.open(conf, run_id, role, ident, start_timeout_s=5)
    try:
        yield svc
    finally:
        svc.close()
