"""Child processes of a run: started in their own session, ended by PID, never by name."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

from formation.errors import RuntimeFailure
from shell import DUMP_SIGNAL, MEMBER_ENV, MEMBERS_FILE_ENV

# One BLAS thread per service: a run is many processes on few cores, and OpenBLAS's idle
# workers spin-wait, taking the cores the other services need (seen: a 1,000-agent pool
# process spent most of its CPU in blas_thread_server). The user's environment wins.
# Zenoh's own threads are left as they are: all of them on one (ZENOH_RUNTIME with
# `handover: app`) halved the router's CPU but stalled realtime runs, in the router alone too.
SERVICE_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port nobody listens on right now (the OS picks it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def wait_for_port(host: str, port: int, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            with socket.create_connection((host, port), timeout=0.2):
                return
        except OSError:
            time.sleep(0.01)
    raise RuntimeFailure(f"nothing listens on {host}:{port} after {timeout_s:g} s")


@dataclass
class Child:
    name: str
    proc: subprocess.Popen[bytes]
    log_path: Path

    @property
    def pid(self) -> int:
        return self.proc.pid

    def tail(self, lines: int = 15) -> str:
        try:
            text = self.log_path.read_text(errors="replace").splitlines()
        except OSError:
            return ""
        return "\n".join(text[-lines:])


@dataclass
class ProcessGroup:
    """Every process a run started; :meth:`stop_all` ends each by PID (TERM, then KILL)."""

    log_dir: Path
    children: list[Child] = field(default_factory=list)
    on_start: Callable[[], object] | None = (
        None  # called after each start (e.g. to write pids.json)
    )
    # The run's team (shell.zenoh_config): each child is a member under its name, a restart
    # ("agent-3.1") under the name it restarts.
    members_file: Path | None = None

    def start(self, name: str, module: str, *args: str, env: dict[str, str] | None = None) -> Child:
        self.log_dir.mkdir(parents=True, exist_ok=True)
        log_path = self.log_dir / f"{name.replace('/', '-')}.log"
        team = (
            {MEMBERS_FILE_ENV: str(self.members_file), MEMBER_ENV: name.split(".")[0]}
            if self.members_file
            else {}
        )
        with log_path.open("wb") as log:
            proc = subprocess.Popen(
                # -P: the services import what the launcher imported, not a checkout in the cwd
                [sys.executable, "-P", "-m", module, *args],
                stdout=log,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                env={**SERVICE_ENV, **os.environ, **team, **(env or {})},
                start_new_session=True,  # Ctrl-C reaches the launcher only; it stops children in order
            )
        child = Child(name, proc, log_path)
        self.children.append(child)
        if self.on_start is not None:
            self.on_start()
        return child

    def pid_map(self) -> dict[str, int]:
        return {c.name: c.pid for c in self.children}

    def failed(self) -> list[Child]:
        """Children that exited with a non-zero code."""
        return [c for c in self.children if c.proc.poll() not in (None, 0)]

    def stop(self, child: Child, timeout_s: float = 5.0) -> int | None:
        if child.proc.poll() is None:
            child.proc.send_signal(signal.SIGTERM)
            try:
                child.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                child.proc.kill()
                child.proc.wait(5.0)
        return child.proc.returncode

    def dump_stacks(self, settle_s: float = 0.2, timeout_s: float = 3.0) -> None:
        """Ask every live child for its threads' stacks (into its log); wait until the logs settle."""
        live = [c for c in self.children if c.proc.poll() is None]
        for child in live:
            with contextlib.suppress(ProcessLookupError):
                os.kill(child.pid, DUMP_SIGNAL)
        sizes, stable_since = None, time.monotonic()
        deadline = stable_since + timeout_s
        while time.monotonic() < deadline:
            now = [c.log_path.stat().st_size if c.log_path.exists() else 0 for c in live]
            if now != sizes:
                sizes, stable_since = now, time.monotonic()
            elif time.monotonic() - stable_since >= settle_s:
                return
            time.sleep(0.02)

    def wait_for(
        self,
        cond: Callable[[], bool],
        timeout_s: float,
        what: str,
        detail: Callable[[], str] | None = None,
        ignore: Iterable[object] | Callable[[], Iterable[object]] = (),
        check: Callable[[], None] | None = None,
    ) -> None:
        """Wait for ``cond``; a child failing meanwhile is an error unless among the ``ignore``d
        losses (or pids, or a callable giving them); ``check()`` is called first each time."""
        deadline = time.monotonic() + timeout_s
        while not cond():
            if check is not None:
                check()
            gone = ignore() if callable(ignore) else ignore
            lost = {getattr(loss, "pid", loss) for loss in gone}  # losses, or planned pids
            failed = [c for c in self.failed() if c.pid not in lost]
            if failed:
                c = failed[0]
                raise RuntimeFailure(
                    f"{c.name} (pid {c.pid}) exited with code {c.proc.returncode} while waiting "
                    f"for {what}; its log is {c.log_path}:\n{c.tail()}"
                )
            if time.monotonic() > deadline:
                more = "" if detail is None else detail()
                self.dump_stacks()
                raise RuntimeFailure(
                    f"timed out after {timeout_s:g} s waiting for {what}{more}; "
                    f"each process's threads are at the end of its log in {self.log_dir}"
                )
            time.sleep(0.01)

    def stop_all(self) -> None:
        """End children newest first, so the router and the recorder (started first) go last."""
        for child in reversed(self.children):
            self.stop(child)

    @property
    def pids(self) -> list[int]:
        return [c.pid for c in self.children]
