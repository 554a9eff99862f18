"""Benchmark of netem's link models (netem/links/models.py): decisions per second, per packet and batched.

Run ``python bench/bench_netem_models.py [--seed S] [--quick]``. For each model
it measures ``LinkModel.decide`` called once per packet on consecutive epochs
(the netem process's path: blocks of 1,024 epochs computed vectorised, then
served from a cache), ``schedule`` (one link, all epochs at once) and
``delivery_matrix`` (100 links at once, the simulator's path). The baseline is
per-packet ``decide`` on a Bernoulli link, measured in the same run; every rate
is also given as a ratio to it. Two slower per-packet paths are listed too: a
realtime outage window (``time_s`` given) and a second packet of an epoch
(``seq = 1``, drawn one by one). Times are the best of three runs.
"""

from __future__ import annotations

import os

os.environ["OPENBLAS_NUM_THREADS"] = "1"  # before numpy: one core, comparable numbers
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import time
from collections.abc import Callable
from functools import partial

import numpy as np

from formation.linkmodels import (
    Bernoulli,
    Delay,
    Duplicate,
    GilbertElliott,
    LinkModelSpec,
    Markov4,
    Outage,
    Reorder,
)
from netem.links.models import LinkModel, delivery_matrix, schedule
from shell import settle_heap

SEED = 20240601
N_LINKS = 100  # links of the delivery_matrix case

STACKS: dict[str, list[LinkModelSpec]] = {
    "bernoulli": [Bernoulli(p_loss=0.1)],
    "outage+bernoulli": [Outage(start=100, end=200, every=1000), Bernoulli(p_loss=0.1)],
    "bernoulli corr": [Bernoulli(p_loss=0.3, correlation=0.5)],
    "gilbert-elliott": [GilbertElliott(p=0.05, r=0.3, **{"1-h": 0.8, "1-k": 0.02})],
    "markov4": [Markov4(p13=0.02, p31=0.3, p32=0.1, p23=0.4, p14=0.01)],
    "delay normal": [
        Delay(epochs=2, jitter_epochs=1, ms=20.0, jitter_ms=5.0, distribution="normal")
    ],
    "full stack": [
        Outage(start=100, end=200, every=1000),
        GilbertElliott(p=0.05, r=0.3),
        Delay(epochs=2, jitter_epochs=1, ms=20.0, jitter_ms=5.0),
        Duplicate(p=0.01),
        Reorder(p=0.1, gap=3),
    ],
}


def best_of(fn: Callable[[], object], repeats: int = 3) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def per_packet_rate(stack: list[LinkModelSpec], seed: int, n: int) -> float:
    # netem decides with its heap settled (shell.settle_heap): what the long schedules above
    # loaded (numba, for 2^18 draws or more) must not be walked by every collection here
    settle_heap()

    def go() -> None:
        model = LinkModel(stack, seed, 1, 2)  # fresh: block computation is part of the cost
        decide = model.decide
        for k in range(n):
            decide(k)

    return n / best_of(go)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=SEED)
    parser.add_argument("--quick", action="store_true", help="fewer epochs, for a smoke run")
    args = parser.parse_args(argv)
    seed: int = args.seed
    n_packet = 20_000 if args.quick else 200_000
    n_batch = 50_000 if args.quick else 500_000
    n_matrix = 1_000 if args.quick else 10_000
    links = np.array([(i % 10 + 1, (i * 3) % 17 + 1) for i in range(N_LINKS)])
    t_start = time.perf_counter()

    baseline = per_packet_rate(STACKS["bernoulli"], seed, n_packet)
    print(f"netem link models, seed {seed}; rates in decisions per second (best of 3)")
    print(f"baseline: per-packet decide, bernoulli: {baseline:,.0f}/s")
    print()
    header = f"{'model':<18} {'decide':>12} {'×':>6} {'schedule':>12} {'×':>6}"
    header += f" {'matrix ' + str(N_LINKS) + ' links':>18} {'×':>6}"
    print(header)
    print("-" * len(header))
    for name, stack in STACKS.items():
        packet = baseline if name == "bernoulli" else per_packet_rate(stack, seed, n_packet)
        batch = n_batch / best_of(partial(schedule, stack, seed, 1, 2, n_batch))
        stacks = [stack] * N_LINKS
        matrix = (N_LINKS * n_matrix) / best_of(
            partial(delivery_matrix, stacks, seed, links, n_matrix)
        )
        print(
            f"{name:<18} {packet:>12,.0f} {packet / baseline:>6.2f} {batch:>12,.0f}"
            f" {batch / baseline:>6.1f} {matrix:>18,.0f} {matrix / baseline:>6.1f}"
        )

    print()
    timed: list[LinkModelSpec] = [Outage(start_s=10.0, end_s=20.0), Bernoulli(p_loss=0.1)]
    n_slow = n_packet // 4

    def realtime() -> None:
        model = LinkModel(timed, seed, 1, 2)
        for k in range(n_slow):
            model.decide(k, time_s=0.05 * k)

    rate = n_slow / best_of(realtime)
    print(
        f"per-packet decide with a realtime outage (time_s): {rate:,.0f}/s ({rate / baseline:.2f}×)"
    )
    delayed = STACKS["delay normal"]
    n_seq = n_packet // 4

    def second_packet() -> None:
        model = LinkModel(delayed, seed, 1, 2)
        for k in range(n_seq):
            model.decide(k, seq=1)

    rate = n_seq / best_of(second_packet)
    print(
        f"per-packet decide of a second packet (seq = 1), delay: {rate:,.0f}/s ({rate / baseline:.3f}×)"
    )
    print(f"total {time.perf_counter() - t_start:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
