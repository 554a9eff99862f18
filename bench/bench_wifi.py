"""The 802.11 air model (netem/links/wifi): saturation against Bianchi, and what a phase costs.

Run ``python -m bench wifi [--quick] [--speed-only | --bianchi-only] [--seed S] [--seeds K]``.
Two measurements, each against a baseline computed or measured in the same run:

1. **Bianchi**: the model's saturation throughput (802.11a, 1,500 B, basic access, stations
   within a metre) against Bianchi's analytical model and against the form ns-3 validates its
   DCF with (the slot after a success open only to its sender), at 6 and 54 Mb/s for
   n = 5 .. 50 (``netem.links.wifi.saturation``): the mean ratio over the seeds, ± twice its
   standard error, and the model's collision probability per attempt beside Bianchi's (the
   reference form takes Bianchi's ``τ`` and ``p``).
2. **Speed**: the CPU time of an epoch's three phases on the air for 5, 20 and 50 agents on a
   grid spaced 5 m (the states, each agent broadcasting 200 B at 6 Mb/s ready at a uniform
   offset in the first 2 ms; the n − 1 unicast reports to agent 0; agent 0's n − 1 unicast
   estimates), through the compiled loop and through the loop in Python (``reference_phase``,
   alternating), against the simulator's epoch of ``scenarios/grid20.toml`` with Bernoulli
   links and netem's Bernoulli decision of grid20's 380 directed links.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import time
from collections.abc import Callable

import numpy as np

from bench.netem_rig import ROOT
from formation.linkmodels import Bernoulli
from formation.scenario import Scenario
from netem.links.models import LinkModel
from netem.links.wifi import BROADCAST, AirConfig, Frames, Key, PhaseOutcome, decide_phase
from netem.links.wifi.dcf import reference_phase
from netem.links.wifi.saturation import (
    backoff_stages,
    bianchi_ns3_reference_bps,
    bianchi_tau,
    bianchi_throughput_bps,
    saturated_run,
)
from testbed.sim.simulate import simulate

Phase = Callable[[AirConfig, np.ndarray, Frames, Key], PhaseOutcome]
SEED = 42
STATE_BYTES = 200 + 36  # a state's payload, UDP/IP and LLC/SNAP headers


def bianchi(seed: int, quick: bool, seeds: int) -> None:
    runs = range(seed, seed + seeds)
    per = 1200 if quick else 3000
    print(
        f"1. saturation throughput, 802.11a, 1500 B, basic access, {per} frames a run, "
        f"seeds {runs.start}..{runs.stop - 1}; ratios: mean ± 2 standard errors; "
        "p: collided attempts ÷ attempts"
    )
    print(
        f"   {'rate':>5} {'n':>3} {'Bianchi':>8} {'ns-3 ref':>8} {'model':>7} "
        f"{'model/Bianchi':>15} {'model/ns-3 ref':>15} {'p model':>8} {'Bianchi':>8}"
    )
    for rate in (6.0, 54.0):
        config = AirConfig(rate_mbps=rate)
        w, m = backoff_stages(config)
        for n in (5, 10, 20, 50):
            chain = bianchi_throughput_bps(config, n, 1500)
            reference = bianchi_ns3_reference_bps(config, n, 1500)
            counts = [saturated_run(config, n, 1500, max(30, per // n), s) for s in runs]
            measured = np.array([c.throughput_bps for c in counts])
            collided = np.mean([c.p_collision for c in counts])
            two_se = 2 * measured.std(ddof=1) / np.sqrt(len(runs))
            print(
                f"   {rate:5g} {n:3d} {chain / 1e6:8.3f} {reference / 1e6:8.3f} "
                f"{measured.mean() / 1e6:7.3f} "
                f"{measured.mean() / chain:7.3f} ± {two_se / chain:5.3f} "
                f"{measured.mean() / reference:7.3f} ± {two_se / reference:5.3f} "
                f"{collided:8.3f} {bianchi_tau(n, w, m)[1]:8.3f}",
                flush=True,
            )


def epoch_frames(n: int, rng: np.random.Generator) -> list[Frames]:
    """The three phases of an epoch on the air: states, reports to agent 0, its estimates."""
    others = np.arange(1, n)
    return [
        Frames.of(np.arange(n), BROADCAST, STATE_BYTES, rng.integers(0, 2_000_000, n)),
        Frames.of(others, 0, STATE_BYTES, rng.integers(0, 2_000_000, n - 1)),
        Frames.of(0, others, STATE_BYTES, 0),
    ]


def cpu_best(fn: Callable[[], object], repeat: int = 3) -> float:
    """The least CPU time of ``repeat`` calls [s]."""
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    return min(times)


def team(n: int) -> np.ndarray:
    """``n`` agents on a grid spaced 5 m, five to a row (grid20's layout at 20)."""
    return np.array([[i % 5, i // 5] for i in range(n)], dtype=np.float64) * 5.0


def air_epochs(decide: Phase, positions: np.ndarray, plans: list[list[Frames]], seed: int) -> float:
    """The CPU time of deciding every phase of ``plans`` [s]."""
    config = AirConfig()
    t0 = time.process_time()
    for k, plan in enumerate(plans):
        for phase, frames in enumerate(plan):
            decide(config, positions, frames, Key(seed, k, phase))
    return time.process_time() - t0


def speed(seed: int, epochs: int) -> None:
    scenario = Scenario.from_file(ROOT / "scenarios/grid20.toml")
    n = scenario.n
    links = [
        LinkModel([Bernoulli(p_loss=0.1)], seed, i, j) for i in range(n) for j in range(n) if i != j
    ]

    def bernoulli() -> None:
        for k in range(epochs):
            for model in links:
                model.decide(k)

    sim_scenario = scenario.with_overrides(epochs=epochs)
    base = cpu_best(bernoulli) / epochs
    sim = cpu_best(lambda: simulate(sim_scenario, seed=seed)) / epochs
    print(f"2. an epoch's three phases on the air, {epochs} epochs, seed {seed}, CPU, best of 3")
    print(f"   Bernoulli decide, {len(links)} links (grid20)   {base * 1e3:8.3f} ms/epoch")
    print(f"   simulator epoch, grid20, Bernoulli links  {sim * 1e3:8.3f} ms/epoch")
    print(
        f"   {'agents':>6} {'Python loop ms':>14} {'compiled ms':>11} {'speed-up':>8} "
        f"{'÷ simulator epoch':>17} {'÷ Bernoulli':>11}"
    )
    reference_epochs = max(2, epochs // 5)  # the loop in Python is the slow one
    for agents in (5, 20, 50):
        positions = team(agents)
        rng = np.random.default_rng(seed)
        plans = [epoch_frames(agents, rng) for _ in range(epochs)]
        air_epochs(decide_phase, positions, plans[:1], seed)  # loaded (or compiled) once
        compiled, python = [], []
        for _ in range(3):  # alternating, so both see the same load
            compiled.append(air_epochs(decide_phase, positions, plans, seed))
            python.append(air_epochs(reference_phase, positions, plans[:reference_epochs], seed))
        fast, slow = min(compiled) / epochs, min(python) / reference_epochs
        print(
            f"   {agents:6d} {slow * 1e3:14.3f} {fast * 1e3:11.3f} {slow / fast:7.1f}× "
            f"{fast / sim:16.2f}× {fast / base:10.2f}×",
            flush=True,
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=SEED)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--seeds", type=int, default=3, help="runs per case of the Bianchi table")
    only = parser.add_mutually_exclusive_group()
    only.add_argument("--speed-only", action="store_true", help="skip the Bianchi table")
    only.add_argument("--bianchi-only", action="store_true", help="skip the speed table")
    args = parser.parse_args()
    if not args.speed_only:
        bianchi(args.seed, args.quick, args.seeds)
    if not args.bianchi_only:
        speed(args.seed, 20 if args.quick else 100)


if __name__ == "__main__":
    main()
