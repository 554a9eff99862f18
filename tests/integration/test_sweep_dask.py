"""``formation sweep --scheduler``: a real Dask scheduler and workers as processes on 127.0.0.1.

The tables must be byte-identical to the local pool's, also when the workers are killed in the
middle of a sweep (new workers finish it) and when the sweep itself is interrupted (the local pool
finishes it from the CSV).
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from formation.errors import SweepError
from testbed.cli import main
from testbed.experiments.sweep import read_rows
from testkit.dask_processes import DaskProcesses, child_env, dask_cluster, end

pytestmark = [pytest.mark.integration, pytest.mark.slow]

WAIT_S = 60.0
TABLES = ("runs.csv", "critical.md", "success.md", "phase.png")
# paper.toml alone: 5 rates × 2 strategies × 160 seeds = 1,600 cells of 100 epochs. Dask's
# chunks get 40 seeds (executors.seeds_per_task), so 4 tasks: the workers die between them.
SWEEP = (
    "--topology",
    "none",
    "--loss",
    "0:1:0.25",
    "--strategy",
    "hold,estimate",
    "--seeds",
    "160",
    "--seed",
    "1",
    "--epochs",
    "100",
)
CELLS = 5 * 2 * 160


@pytest.fixture
def cluster(tmp_path: Path) -> Iterator[DaskProcesses]:
    with dask_cluster(tmp_path / "dask-logs", workers=2) as c:
        yield c


def sweep(paper_path: Path, out: Path, *extra: str, log: Path) -> subprocess.Popen[bytes]:
    """``formation sweep`` as its own process."""
    with log.open("wb") as f:
        return subprocess.Popen(
            [
                sys.executable,
                "-m",
                "testbed.cli",
                "sweep",
                str(paper_path),
                *SWEEP,
                "--out",
                str(out),
                *extra,
            ],
            env=child_env(),
            stdout=f,
            stderr=subprocess.STDOUT,
        )


def wait_for(
    condition: Callable[[], bool], proc: subprocess.Popen[bytes], what: str, log: Path
) -> None:
    deadline = time.monotonic() + WAIT_S
    while not condition():
        if proc.poll() is not None:
            pytest.fail(
                f"sweep exited ({proc.returncode}) before {what}:\n{log.read_text()[-3000:]}"
            )
        if time.monotonic() > deadline:
            pytest.fail(f"timed out waiting for {what}:\n{log.read_text()[-3000:]}")
        time.sleep(0.02)


def rows_in(out: Path) -> int:
    try:
        return len(read_rows(out / "runs.csv"))
    except SweepError:  # the header half written
        return 0


def finish(proc: subprocess.Popen[bytes], log: Path) -> int:
    try:
        return proc.wait(timeout=WAIT_S)
    except subprocess.TimeoutExpired:
        pytest.fail(f"sweep did not finish in {WAIT_S:g} s:\n{log.read_text()[-3000:]}")


def assert_same_tables(a: Path, b: Path) -> None:
    for name in TABLES:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name


def test_sweep_on_a_dask_cluster_matches_the_local_pool_and_survives_its_workers(
    cluster: DaskProcesses, paper_path: Path, tmp_path: Path
) -> None:
    listening = cluster.listening()
    assert len(listening) >= 6 and all(a.startswith("127.") for a in listening), listening
    pool = tmp_path / "pool"
    assert main(["sweep", str(paper_path), *SWEEP, "--out", str(pool), "--jobs", "2"]) == 0
    assert len(read_rows(pool / "runs.csv")) == CELLS

    # through the scheduler; its workers die mid-sweep, new ones join and the same sweep completes
    killed, log = tmp_path / "killed", tmp_path / "killed.log"
    proc = sweep(paper_path, killed, "--scheduler", cluster.address, log=log)
    try:
        wait_for(lambda: rows_in(killed) > 0, proc, "the first rows", log)
        cluster.kill_workers()
        # rows came in while tasks were left: streamed as tasks finish, not written at the end
        assert cluster.unfinished_tasks() > 0 and 0 < rows_in(killed) < CELLS
        cluster.start_workers(2)
        assert finish(proc, log) == 0, log.read_text()[-3000:]
    finally:
        end(proc)
    assert_same_tables(pool, killed)

    # the workers die and the sweep is interrupted; the local pool runs the rest from the CSV
    moved, log = tmp_path / "moved", tmp_path / "moved.log"
    proc = sweep(paper_path, moved, "--scheduler", cluster.address, log=log)
    try:
        wait_for(lambda: rows_in(moved) > 0, proc, "the first rows", log)
        cluster.kill_workers()
        proc.send_signal(signal.SIGINT)
        assert finish(proc, log) == 130, log.read_text()[-3000:]
    finally:
        end(proc)
    kept = rows_in(moved)
    assert 0 < kept < CELLS
    assert main(["sweep", str(paper_path), *SWEEP, "--out", str(moved), "--jobs", "2"]) == 0
    assert_same_tables(pool, moved)


def test_sweep_on_a_local_dask_cluster_matches_the_local_pool(
    paper_path: Path, tmp_path: Path
) -> None:
    small = ["--topology", "none", "--loss", "0,0.5", "--strategy", "hold", "--seeds", "4"]
    pool, local, log = tmp_path / "pool", tmp_path / "local", tmp_path / "local.log"
    assert main(["sweep", str(paper_path), *small, "--out", str(pool), "--jobs", "2"]) == 0
    cli = [sys.executable, "-m", "testbed.cli", "sweep", str(paper_path), *small]
    with log.open("wb") as f:
        proc = subprocess.Popen(
            [*cli, "--out", str(local), "--scheduler", "local:2"],
            env=child_env(),
            stdout=f,
            stderr=subprocess.STDOUT,
        )
    try:
        assert finish(proc, log) == 0, log.read_text()[-3000:]
    finally:
        end(proc)
    assert_same_tables(pool, local)
