"""A Dask scheduler and workers as real processes on 127.0.0.1, every one ended by its PID.

A test harness, not part of the product (not in the wheel): used by
``tests/integration/test_sweep_dask.py`` and ``bench/bench_sweep.py``. The scheduler is
``dask scheduler --host 127.0.0.1 --port P`` on a free port; each worker is
``dask worker tcp://127.0.0.1:P --host 127.0.0.1 --nworkers 1 --nthreads 1 --no-nanny``
(without a nanny its PID is the worker itself: a nanny killed by PID would leave its worker
running). Both get ``--dashboard-address 127.0.0.1:0``: with ``--no-dashboard`` their HTTP
servers still listen, on 0.0.0.0:8787 and 0.0.0.0:<random>. Readiness is the scheduler's port answering and then the scheduler reporting the
workers, never a fixed wait.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import distributed
import psutil

from testbed.runtime.processes import free_port, wait_for_port

HOST = "127.0.0.1"
WAIT_S = 60.0
# One BLAS thread per worker, as the local pool and the launcher's services have.
ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def child_env() -> dict[str, str]:
    return {**os.environ, **ENV}


def end(proc: subprocess.Popen[bytes]) -> None:
    """Kill ``proc`` by PID if it still runs, and reap it."""
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=10)


class DaskProcesses:
    """``dask scheduler`` and ``dask worker`` processes; :meth:`end` stops every one by PID."""

    def __init__(self, logs: Path) -> None:
        self.logs = logs
        self.port = free_port(HOST)
        self.address = f"tcp://{HOST}:{self.port}"
        self.procs: list[subprocess.Popen[bytes]] = []
        self.workers: list[subprocess.Popen[bytes]] = []

    def _start(self, name: str, *args: str) -> subprocess.Popen[bytes]:
        with (self.logs / f"{name}.log").open("wb") as log:
            proc = subprocess.Popen(
                [sys.executable, "-m", "dask", *args],
                env=child_env(),
                stdout=log,
                stderr=subprocess.STDOUT,
            )
        self.procs.append(proc)
        return proc

    def start_scheduler(self) -> None:
        # --idle-timeout: a scheduler its starter failed to end leaves by itself.
        self._start(
            "scheduler",
            "scheduler",
            "--host",
            HOST,
            "--port",
            str(self.port),
            "--dashboard-address",
            f"{HOST}:0",
            "--idle-timeout",
            "300",
        )
        wait_for_port(HOST, self.port, WAIT_S)

    def start_workers(self, count: int) -> None:
        """``count`` single-threaded workers; returns once the scheduler has every live one."""
        for _ in range(count):
            self.workers.append(
                self._start(
                    f"worker-{len(self.workers)}",
                    "worker",
                    self.address,
                    "--host",
                    HOST,
                    "--nworkers",
                    "1",
                    "--nthreads",
                    "1",
                    "--no-nanny",
                    "--dashboard-address",
                    f"{HOST}:0",
                    "--death-timeout",
                    "60",
                )
            )
        with self.client() as client:
            client.wait_for_workers(len(self.live_workers()), timeout=WAIT_S)

    def client(self) -> distributed.Client:
        client: distributed.Client = distributed.Client(  # type: ignore[no-untyped-call]
            self.address, timeout=WAIT_S, set_as_default=False
        )
        return client

    def live_workers(self) -> list[subprocess.Popen[bytes]]:
        return [w for w in self.workers if w.poll() is None]

    def unfinished_tasks(self) -> int:
        """Tasks the scheduler holds that have no result yet (waiting for a worker, or running)."""
        with self.client() as client:
            count: int = client.run_on_scheduler(
                lambda dask_scheduler: sum(
                    ts.state in ("no-worker", "queued", "waiting", "processing")
                    for ts in dask_scheduler.tasks.values()
                )
            )
        return count

    def listening(self) -> list[str]:
        """``HOST:PORT`` of every socket the live processes listen on."""
        out = []
        for proc in self.procs:
            if proc.poll() is None:
                for c in psutil.Process(proc.pid).net_connections(kind="inet"):
                    if c.status == psutil.CONN_LISTEN:
                        out.append(f"{c.laddr.ip}:{c.laddr.port}")
        return out

    def kill_workers(self) -> None:
        for w in self.live_workers():
            os.kill(w.pid, signal.SIGKILL)
            w.wait(timeout=10)

    def end(self) -> None:
        for proc in reversed(self.procs):
            end(proc)


@contextlib.contextmanager
def dask_cluster(logs: Path, workers: int) -> Iterator[DaskProcesses]:
    """A scheduler and ``workers`` workers, their logs in ``logs`` (made); ended by PID on exit."""
    logs.mkdir(parents=True, exist_ok=True)
    cluster = DaskProcesses(logs)
    try:
        cluster.start_scheduler()
        cluster.start_workers(workers)
        yield cluster
    finally:
        cluster.end()


__all__ = ["HOST", "DaskProcesses", "child_env", "dask_cluster", "end"]
