"""Executors of a sweep: ``--scheduler`` parsing, chunk sizing, the local pool, no Dask needed."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from formation.errors import ExecutorError
from formation.scenario import Scenario
from testbed.cli import main
from testbed.experiments.executors import (
    DASK_TASK_OVERHEAD_S,
    DaskCluster,
    LocalPool,
    executor_for,
    parse_scheduler,
    seeds_per_task,
)
from testbed.experiments.sweep import SweepSpec, plan_chunks, run_chunk

ROOT = Path(__file__).resolve().parents[3]


def test_scheduler_forms() -> None:
    assert parse_scheduler("local:3") == 3
    assert parse_scheduler("tcp://127.0.0.1:8786") is None
    assert parse_scheduler("tls://scheduler.example:8786") is None
    assert isinstance(executor_for(None, 2), LocalPool)
    assert executor_for("local:2") == DaskCluster("local:2")
    for bad in ("local:0", "local:x", "127.0.0.1:8786", "tcp://host", "tcp://h:1/x", "udp://h:1"):
        with pytest.raises(
            ExecutorError, match=rf"--scheduler '{bad}': .*expected tcp://HOST:PORT"
        ):
            parse_scheduler(bad)
    with pytest.raises(ExecutorError, match="--jobs 2 with --scheduler local:2: --jobs sizes"):
        executor_for("local:2", 2)


def test_cli_names_a_bad_scheduler(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert main(["sweep", "--scheduler", "local:0", "--out", str(tmp_path)]) == 1
    assert "formation sweep: error: --scheduler 'local:0': local:N needs N ≥ 1" in (
        capsys.readouterr().err
    )


def test_chunks_are_long_enough_for_their_overhead() -> None:
    # 84 cells per seed (21 rates × 4 strategies) of 200 epochs: ≥ 168 ms a seed, so Dask's
    # 20 ms stays under 5 % from 3 seeds (12 %, then 6 %, then 4 %)
    assert seeds_per_task(1, 84, 200, DASK_TASK_OVERHEAD_S) == 3
    assert seeds_per_task(10, 84, 200, DASK_TASK_OVERHEAD_S) == 10  # never fewer than asked
    assert seeds_per_task(1, 1, 50, DASK_TASK_OVERHEAD_S) == 800
    assert seeds_per_task(3, 4, 200, 0.0) == 3  # one process: no overhead, the chunking as asked
    for cells, epochs in ((1, 1), (7, 33), (84, 200), (1000, 500)):
        s = seeds_per_task(1, cells, epochs, DASK_TASK_OVERHEAD_S)
        task_s = s * cells * epochs * 1e-5
        assert DASK_TASK_OVERHEAD_S / task_s <= 0.05


def test_local_pool_yields_every_result(paper: Scenario) -> None:
    spec = SweepSpec((("paper", paper),), (0.0, 0.5), ("hold",), (1, 2, 3, 4), seeds_per_chunk=2)
    chunks = plan_chunks(spec, set())
    assert len(chunks) == 2
    serial = list(LocalPool(1).map_unordered(run_chunk, chunks))
    pooled = list(LocalPool(2).map_unordered(run_chunk, chunks))
    key = lambda rows: rows[0]["seed"]  # noqa: E731
    assert sorted(pooled, key=key) == sorted(serial, key=key)


def test_the_local_pool_needs_no_dask(tmp_path: Path) -> None:
    """With ``dask``/``distributed`` unimportable, the default sweep runs; ``--scheduler`` says why not."""
    script = textwrap.dedent(
        f"""
        import sys
        class NoDask:
            def find_spec(self, name, path=None, target=None):
                if name.split(".")[0] in ("dask", "distributed"):
                    raise ImportError(f"No module named {{name!r}}")
        sys.meta_path.insert(0, NoDask())
        from testbed.cli import main
        args = ["sweep", "{ROOT / "scenarios" / "paper.toml"}", "--topology", "none",
                "--loss", "0,0.5", "--strategy", "hold", "--seeds", "2", "--epochs", "20"]
        assert main([*args, "--out", "{tmp_path / "pool"}"]) == 0
        assert "distributed" not in sys.modules
        sys.exit(main([*args, "--out", "{tmp_path / "dask"}", "--scheduler", "local:2"]))
        """
    )
    proc = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120, cwd=tmp_path
    )
    assert proc.returncode == 1, proc.stderr
    assert (tmp_path / "pool" / "critical.md").exists()
    assert (
        "formation sweep: error: --scheduler local:2: needs Dask "
        "(pip install 'formation-testbed[dask]')" in proc.stderr
    )
