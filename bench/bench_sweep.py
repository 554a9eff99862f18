"""Sweep throughput: cells per second of ``formation sweep`` against a loop of ``simulate()``.

A cell is one topology × strategy × loss rate × seed run of 200 epochs. The baseline, measured in
the same run, is a single-process loop of ``testbed.sim.simulate.simulate`` over a sample of the same
cells (every topology × strategy at loss 0.5). The sweep runs batched (``testbed.sim.batch``) in one
process and on two worker processes, from scratch each time. Prints the seed, the load average
(wall times on a shared machine are loaded; CPU seconds are not) and the time the full default
sweep (21 loss rates × 4 strategies × 50 seeds × 4 topologies = 16,800 cells) would take at the
measured rate.

Run ``python bench/bench_sweep.py [--seed S] [--quick]``.
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
from pathlib import Path

from formation.scenario import Scenario, StrategyName
from testbed.experiments.lossy import with_loss
from testbed.experiments.sweep import SweepSpec, run_sweep
from testbed.sim.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]
SEED = 1
EPOCHS = 200
TOPOLOGIES = ("paper", "ring8", "grid20", "octahedron3d")
STRATEGIES: tuple[StrategyName, ...] = ("zero", "hold", "estimate", "blend")
FULL_CELLS = 21 * 4 * 50 * 4


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


def sweep_rate(spec: SweepSpec, jobs: int) -> tuple[float, float]:
    """Cells per second (wall, CPU of this process and its workers) of a sweep from scratch."""
    with tempfile.TemporaryDirectory() as tmp:
        w0, c0 = time.perf_counter(), _cpu()
        run_sweep(spec, Path(tmp), jobs=jobs)
        wall, cpu = time.perf_counter() - w0, _cpu() - c0
    cells = len(spec.keys())
    return cells / wall, cells / cpu


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=SEED, help="first seed")
    parser.add_argument("--quick", action="store_true", help="a smaller sweep, for a smoke run")
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
    base_wall, base_cpu, base_cells = baseline_rate(topologies, seed)
    print(
        f"baseline: loop of simulate() in one process, {base_cells} cells (every topology × strategy, loss 0.5)"
    )
    print()
    header = f"{'how':<34} {'cells/s wall':>12} {'×':>6} {'cells/s CPU':>12} {'×':>6} {'full sweep [s]':>15}"
    print(header)
    print("-" * len(header))
    rows = [("simulate() loop, 1 process", base_wall, base_cpu)]
    rows.append(("batched sweep, 1 process", *sweep_rate(spec, 1)))
    rows.append(("batched sweep, 2 processes", *sweep_rate(spec, 2)))
    for name, wall, cpu in rows:
        print(
            f"{name:<34} {wall:>12.1f} {wall / base_wall:>6.1f} {cpu:>12.1f} {cpu / base_cpu:>6.1f}"
            f" {FULL_CELLS / wall:>15.0f}"
        )
    print(f"\nfull default sweep = {FULL_CELLS} cells; target: under 180 s on 2 cores")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
