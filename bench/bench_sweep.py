"""Sweep throughput: cells per second of ``formation sweep`` on each executor, against a loop.

A cell is one topology × strategy × loss rate × seed run of 200 epochs. The baseline, measured in
the same run, is a single-process loop of ``testbed.sim.simulate.simulate`` over a sample of the same
cells (every topology × strategy at loss 0.5). The sweep runs batched (``testbed.sim.batch``), from
scratch each time, on: one process; the local pool of 2 processes; ``--scheduler local:2`` (a
``distributed.LocalCluster`` of 2 workers, started and closed inside the timed sweep, as the
command does); and a Dask scheduler with 2 workers running as their own processes on 127.0.0.1
(started before the timing and warmed by a small sweep, as a cluster that is already up would
be; their CPU is read from their PIDs). Every configuration runs ``--repeat`` times, interleaved,
and the best is kept (the machine is shared). Prints the seed, the load average and the time the
full default sweep (21 loss rates × 4 strategies × 50 seeds × 4 topologies = 16,800 cells) would
take at the measured rate.

``--overhead`` measures what one task costs each executor beyond its work: many tasks that each
carry a real chunk in and 84 rows shaped like its own out, but compute nothing. ``testbed.experiments.executors`` sizes Dask's chunks from it.

Run ``python bench/bench_sweep.py [--seed S] [--quick] [--repeat R] [--overhead]``.
"""

from __future__ import annotations

import os

os.environ.setdefault(
    "OPENBLAS_NUM_THREADS", "1"
)  # before numpy: small solves, no spinning threads

import argparse
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import psutil

from formation.scenario import Scenario, StrategyName
from testbed.experiments.executors import DaskCluster, Executor, LocalPool
from testbed.experiments.loss_variants import with_loss
from testbed.experiments.sweep import COLUMNS, Chunk, SweepSpec, plan_chunks, run_sweep
from testbed.sim.simulate import simulate
from testkit.dask_processes import DaskProcesses

ROOT = Path(__file__).resolve().parents[1]
SEED = 1
EPOCHS = 200
TOPOLOGIES = ("paper", "ring8", "grid20", "octahedron3d")
STRATEGIES: tuple[StrategyName, ...] = ("zero", "hold", "estimate", "blend")
FULL_CELLS = 21 * 4 * 50 * 4
OVERHEAD_TASKS = 200


def _cpu() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def baseline_rate(topologies: list[tuple[str, Scenario]], seed: int) -> tuple[float, float, int]:
    """Cells per second (wall, CPU) of a plain loop of ``simulate()``; and the cells run."""
    cells = [
        (with_loss(s, "bernoulli", 0.5), strategy) for _, s in topologies for strategy in STRATEGIES
    ]
    w0, c0 = time.perf_counter(), _cpu()
    for scenario, strategy in cells:
        simulate(scenario, strategy=strategy, seed=seed, epochs=EPOCHS)
    return len(cells) / (time.perf_counter() - w0), len(cells) / (_cpu() - c0), len(cells)


def sweep_rate(
    spec: SweepSpec, executor: Executor, others_cpu: Callable[[], float] = lambda: 0.0
) -> tuple[float, float]:
    """Cells per second (wall, CPU of this process, its children and ``others_cpu``) from scratch."""
    with tempfile.TemporaryDirectory() as tmp:
        w0, c0 = time.perf_counter(), _cpu() + others_cpu()
        run_sweep(spec, Path(tmp), executor=executor)
        wall, cpu = time.perf_counter() - w0, _cpu() + others_cpu() - c0
    cells = len(spec.keys())
    return cells / wall, cells / cpu


def pids_cpu(pids: list[int]) -> Callable[[], float]:
    """CPU seconds so far of the processes ``pids`` (the scheduler's workers)."""
    procs = [psutil.Process(p) for p in pids]

    def total() -> float:
        return sum(sum(p.cpu_times()[:2]) for p in procs)

    return total


def stand_in_rows(chunk: Chunk) -> list[dict[str, str]]:
    """Rows shaped like the chunk's (one per cell, every column, 9 digits): no work to make."""
    return [dict.fromkeys(COLUMNS, "0.123456789") for _ in range(chunk.cells)]


def task_overhead_s(executor: Executor, chunk: Chunk, workers: int) -> float:
    """Seconds one task costs ``executor`` beyond its work, per worker, in steady state.

    Timed from the first result to the last, so starting a cluster or connecting is left out.
    """
    first = last = 0.0
    for i, _ in enumerate(executor.map_unordered(stand_in_rows, [chunk] * OVERHEAD_TASKS)):
        last = time.perf_counter()
        first = first if i else last
    return (last - first) * workers / (OVERHEAD_TASKS - 1)


def overhead_table(topologies: list[tuple[str, Scenario]], cluster: DaskProcesses) -> None:
    name, scenario = next((n, s) for n, s in topologies if n == "grid20")
    losses = tuple(round(0.05 * i, 10) for i in range(21))
    spec = SweepSpec(((name, scenario),), losses, STRATEGIES, (1,), seeds_per_chunk=1)
    chunk = plan_chunks(spec, set())[0]
    print(f"\ntask overhead: {OVERHEAD_TASKS} tasks, each a {name} chunk in and its {chunk.cells}")
    print("rows out with no work, 2 workers; per task per worker:")
    for label, ex in (
        ("local pool, 2 processes", LocalPool(2)),
        ("Dask local:2", DaskCluster("local:2")),
        ("Dask scheduler, 2 workers", DaskCluster(cluster.address)),
    ):
        print(f"  {label:<28} {task_overhead_s(ex, chunk, 2) * 1e3:6.1f} ms")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=SEED, help="first seed")
    parser.add_argument("--quick", action="store_true", help="a smaller sweep, for a smoke run")
    parser.add_argument("--repeat", type=int, default=2, help="runs of each sweep; the best kept")
    parser.add_argument("--overhead", action="store_true", help="also each executor's task cost")
    args = parser.parse_args(argv if argv is not None else [])
    seed: int = args.seed
    topologies = [(t, Scenario.from_file(ROOT / "scenarios" / f"{t}.toml")) for t in TOPOLOGIES]
    losses = (0.0, 0.5, 1.0) if args.quick else tuple(round(0.1 * i, 10) for i in range(11))
    n_seeds = 4 if args.quick else 10
    spec = SweepSpec(
        topologies=tuple(topologies),
        losses=losses,
        strategies=STRATEGIES,
        seeds=tuple(range(seed, seed + n_seeds)),
        epochs=EPOCHS,
        seeds_per_chunk=max(1, n_seeds // 2),
    )
    load = os.getloadavg()[0]
    print(
        f"sweep throughput, seeds {seed}..{seed + n_seeds - 1}, {EPOCHS} epochs per cell, "
        f"{len(spec.keys())} cells; load average {load:.1f} on {os.cpu_count()} cores"
    )
    with tempfile.TemporaryDirectory() as logs:
        cluster = DaskProcesses(Path(logs))
        try:
            cluster.start_scheduler()
            cluster.start_workers(2)
            scheduler = DaskCluster(cluster.address)
            warm = SweepSpec(tuple(topologies), (0.5,), STRATEGIES[:1], (seed,), epochs=10)
            with tempfile.TemporaryDirectory() as tmp:
                run_sweep(warm, Path(tmp), executor=scheduler)  # the workers import testbed
            workers_cpu = pids_cpu([w.pid for w in cluster.workers])
            base_wall, base_cpu, base_cells = baseline_rate(topologies, seed)
            runs: dict[str, Callable[[], tuple[float, float]]] = {
                "batched sweep, 1 process": lambda: sweep_rate(spec, LocalPool(1)),
                "local pool, 2 processes": lambda: sweep_rate(spec, LocalPool(2)),
                "Dask local:2": lambda: sweep_rate(spec, DaskCluster("local:2")),
                "Dask scheduler, 2 workers": lambda: sweep_rate(spec, scheduler, workers_cpu),
            }
            best: dict[str, tuple[float, float]] = {}
            for _ in range(max(1, args.repeat)):
                for name, run in runs.items():
                    wall, cpu = run()
                    prev = best.get(name, (0.0, 0.0))
                    best[name] = (max(prev[0], wall), max(prev[1], cpu))
            if args.overhead:
                overhead_table(topologies, cluster)
        finally:
            cluster.end()
    print(
        f"\nbaseline: loop of simulate() in one process, {base_cells} cells "
        f"(every topology × strategy, loss 0.5); best of {max(1, args.repeat)} runs of each sweep; "
        f"load average now {os.getloadavg()[0]:.1f}"
    )
    pool_wall = best["local pool, 2 processes"][0]
    header = (
        f"{'how':<28} {'cells/s wall':>12} {'×':>6} {'vs pool':>8} {'cells/s CPU':>12} "
        f"{'×':>6} {'full sweep [s]':>15}"
    )
    print(header)
    print("-" * len(header))
    rows = [("simulate() loop, 1 process", base_wall, base_cpu)]
    rows += [(name, wall, cpu) for name, (wall, cpu) in best.items()]
    for name, wall, cpu in rows:
        print(
            f"{name:<28} {wall:>12.1f} {wall / base_wall:>6.1f} {wall / pool_wall:>8.2f}"
            f" {cpu:>12.1f} {cpu / base_cpu:>6.1f} {FULL_CELLS / wall:>15.0f}"
        )
    print(
        f"\nfull default sweep = {FULL_CELLS} cells; targets: under 180 s on 2 cores; "
        "the Dask paths within 10 % of the local pool (vs pool ≥ 0.90)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
