"""Reading a recording at scale: ``load_run`` through the bulk path against the model's path, in one run.

Seed 1. Recordings of ``scenarios/large/team10k.toml`` (10,000 agents) and of a 100-agent
``rigid_team`` (10 % Bernoulli loss, ``hold``), simulated and written as the recorder would
(``testkit.synthetic.write_synthetic``). Baseline, measured in the same run on the same
file: ``decode_run(bulk=False)`` (every message through its pydantic model, every record
through the mcap reader's loop); ratio = baseline time / bulk time. Writing a 10,000-agent
recording takes minutes: ``--keep DIR`` keeps it for the next run.

    python -m bench.bench_load_run [--epochs 100] [--keep DIR]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from analysis import frames
from formation.scenario import Scenario
from recorder.reading.run import decode_run
from testbed.sim.simulate import simulate
from testbed.sim.team_generators import rigid_team
from testkit.synthetic import write_synthetic

ROOT = Path(__file__).resolve().parents[1]
SEED = 1
LOSS = {"formation_default": [{"model": "bernoulli", "p_loss": 0.1}]}


def recording(folder: Path, name: str, scenario: Scenario) -> Path:
    """The synthetic recording of ``scenario`` simulated with seed 1, written once."""
    path = folder / f"{name}-{scenario.n}x{scenario.epochs}.mcap"
    if not path.exists():
        start = time.perf_counter()
        write_synthetic(path, simulate(scenario, seed=SEED))
        print(f"  wrote {path.name} in {time.perf_counter() - start:.0f} s", flush=True)
    return path


def load_seconds(path: Path, bulk: bool) -> tuple[float, float]:
    """Wall and CPU seconds of ``recorder.load_run`` by either path (CPU: this process's own,
    steadier than the wall on a shared machine)."""
    wall, cpu = time.perf_counter(), time.process_time()
    frames(decode_run(path, bulk=bulk))
    return time.perf_counter() - wall, time.process_time() - cpu


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--epochs", type=int, default=100, help="epochs of the 10,000-agent run")
    p.add_argument("--keep", type=Path, help="a folder to keep the recordings in and reuse")
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        large = Scenario.from_file(ROOT / "scenarios/large/team10k.toml")
        small = rigid_team(
            100, 2, 0.1, seed=SEED, epochs=200, network=LOSS, strategy={"name": "hold"}
        )
        runs = [
            recording(folder, "team10k", large.with_overrides(epochs=args.epochs)),
            recording(folder, "rigid", small),
        ]
        print(f"load_run (analysis.frames(read_run(path))), seed {SEED}; baseline: bulk=False")
        print(
            f"{'recording':28} {'MB':>5} {'baseline s':>11} {'bulk s':>7} {'ratio':>6}"
            f" {'baseline CPU s':>15} {'bulk CPU s':>11} {'CPU ratio':>10}"
        )
        for path in runs:
            (base, base_cpu), (bulk, bulk_cpu) = load_seconds(path, False), load_seconds(path, True)
            print(
                f"{path.name:28} {path.stat().st_size / 1e6:5.0f} {base:11.2f} {bulk:7.2f}"
                f" {base / bulk:6.2f} {base_cpu:15.2f} {bulk_cpu:11.2f} {base_cpu / bulk_cpu:10.2f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
