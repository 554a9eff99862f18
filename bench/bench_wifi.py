"""The 802.11 air model (netem/links/wifi): saturation against Bianchi, and what a phase costs.

Run ``python -m bench wifi [--quick] [--seed S]``. Two measurements, each against a baseline
computed or measured in the same run:

1. **Bianchi**: the model's saturation throughput (802.11a, 1,500 B, basic access, stations
   within a metre) against Bianchi's analytical model at 6 and 54 Mb/s for n = 5 .. 50
   (``netem.links.wifi.saturation``): the mean ratio over three seeds and its spread.
2. **Speed**: the time to decide one phase of the 20 agents of ``scenarios/grid20.toml`` (each
   agent broadcasts its 200 B state at 6 Mb/s, ready at a uniform offset in the first 2 ms),
   and an epoch of three phases (the states; 19 unicast reports to agent 0; agent 0's 19
   unicast estimates), against netem's Bernoulli decision of the same packets (one
   ``LinkModel.decide`` per directed link, 380 a phase) and against the simulator's epoch of
   that scenario with Bernoulli links.
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
from netem.links.wifi import BROADCAST, AirConfig, Frames, Key, decide_phase
from netem.links.wifi.saturation import bianchi_throughput_bps, simulated_throughput_bps
from testbed.sim.simulate import simulate

SEED = 42
STATE_BYTES = 200 + 36  # a state's payload, UDP/IP and LLC/SNAP headers


def best(fn: Callable[[], object], repeat: int = 3) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def bianchi(seed: int, quick: bool) -> None:
    seeds = range(seed, seed + 3)
    per = 1200 if quick else 3000
    print(
        f"1. saturation throughput, 802.11a, 1500 B, basic access, {per} frames a run, "
        f"seeds {seeds.start}..{seeds.stop - 1}"
    )
    print(f"   {'rate':>5} {'n':>3} {'Bianchi Mb/s':>13} {'model Mb/s':>11} {'ratio':>6} {'sd':>6}")
    for rate in (6.0, 54.0):
        config = AirConfig(rate_mbps=rate)
        for n in (5, 10, 20, 50):
            expected = bianchi_throughput_bps(config, n, 1500)
            frames = max(30, per // n)
            ratios = np.array(
                [simulated_throughput_bps(config, n, 1500, frames, s) / expected for s in seeds]
            )
            print(
                f"   {rate:5g} {n:3d} {expected / 1e6:13.3f} "
                f"{ratios.mean() * expected / 1e6:11.3f} {ratios.mean():6.3f} {ratios.std(ddof=1):6.3f}",
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


def speed(seed: int, epochs: int) -> None:
    scenario = Scenario.from_file(ROOT / "scenarios/grid20.toml")
    n = scenario.n
    positions = np.array([a.offset for a in scenario.agents]) * 5.0  # a 20 m grid
    rng = np.random.default_rng(seed)
    plans = [epoch_frames(n, rng) for _ in range(epochs)]
    config = AirConfig()
    links = [
        LinkModel([Bernoulli(p_loss=0.1)], seed, i, j) for i in range(n) for j in range(n) if i != j
    ]

    def bernoulli() -> None:
        for k in range(epochs):
            for model in links:
                model.decide(k)

    def state_phase() -> None:
        for k in range(epochs):
            decide_phase(config, positions, plans[k][0], Key(seed, k, 0))

    def air_epoch() -> None:
        for k in range(epochs):
            for phase, frames in enumerate(plans[k]):
                decide_phase(config, positions, frames, Key(seed, k, phase))

    sim_scenario = scenario.with_overrides(epochs=epochs)
    base = best(bernoulli) / epochs
    sim = best(lambda: simulate(sim_scenario, seed=seed)) / epochs
    state = best(state_phase) / epochs
    whole = best(air_epoch) / epochs
    print(f"2. 20 agents (grid20, spaced 5 m), {epochs} epochs, seed {seed}, best of 3")
    print(f"   Bernoulli decide, {len(links)} links          {base * 1e3:8.3f} ms/epoch (baseline)")
    print(f"   simulator epoch, Bernoulli links      {sim * 1e3:8.3f} ms/epoch ({sim / base:.2f}×)")
    print(
        f"   air model, the state phase            {state * 1e3:8.3f} ms/phase ({state / base:.2f}× "
        f"Bernoulli, {state / sim:.2f}× the simulator's epoch)"
    )
    print(
        f"   air model, three phases               {whole * 1e3:8.3f} ms/epoch ({whole / base:.2f}× "
        f"Bernoulli, {whole / sim:.2f}× the simulator's epoch)",
        flush=True,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=SEED)
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    bianchi(args.seed, args.quick)
    speed(args.seed, 20 if args.quick else 100)


if __name__ == "__main__":
    main()
