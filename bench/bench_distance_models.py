"""Benchmark of the distance link models: decisions per second, vectorised and per packet.

Run ``python -m bench distance_models [--seed S] [--quick]``. For ``range``,
``logistic`` and ``log_distance`` (with and without correlated shadowing) it
measures ``delivery_matrix`` over 100 links × 2,000 epochs with every link's length
given (the simulator's vectorised path, ``DeliveryPlan.matrix``), the simulator's
per-epoch path (``DeliveryPlan.at``, 100 links one epoch at a time) and netem's
per-packet ``LinkModel.decide(k, distance_m=d)``. The baseline is a Bernoulli link
measured in the same run on the same paths; ratios are against it. Best of three.
"""

from __future__ import annotations

import os

os.environ["OPENBLAS_NUM_THREADS"] = "1"  # before numpy: one core, comparable numbers
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import time
from collections.abc import Callable

import numpy as np

from formation.linkmodels import Bernoulli, LinkModelSpec, LogDistance, Logistic, Range
from netem import delivery_plan
from netem.links.models import LinkModel, delivery_matrix

SEED = 20240601
N_LINKS = 100

STACKS: dict[str, list[LinkModelSpec]] = {
    "bernoulli": [Bernoulli(p_loss=0.1)],
    "range": [Range(max_range_m=10.0)],
    "logistic": [Logistic(d50_m=10.0, width_m=1.5)],
    "log_distance": [LogDistance(n=3.0, sigma_db=4.0)],
    "log_distance corr": [LogDistance(n=3.0, sigma_db=4.0, shadowing_correlation=0.8)],
}


def best(fn: Callable[[], object], repeat: int = 3) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def measure(
    stack: list[LinkModelSpec],
    ranged: bool,
    seed: int,
    links: np.ndarray,
    dist: np.ndarray,
    n_packets: int,
) -> tuple[float, float, float]:
    """Decisions/s: ``delivery_matrix``, ``DeliveryPlan.at`` per epoch, ``LinkModel.decide``."""
    n_epochs = dist.shape[0]
    stacks = [stack] * N_LINKS
    given = dist if ranged else None
    d_packets = dist[:, 0].tolist() * (n_packets // n_epochs + 1)
    matrix_s = best(lambda: delivery_matrix(stacks, seed, links, n_epochs, distances_m=given))

    def per_epoch() -> None:
        plan = delivery_plan(stacks, seed, links, n_epochs)
        for k in range(n_epochs):
            plan.at(k, dist[k])

    def per_packet() -> None:
        model = LinkModel(stack, seed, 1, 2)
        for k in range(n_packets):
            model.decide(k, distance_m=d_packets[k] if ranged else None)

    decisions = N_LINKS * n_epochs
    return decisions / matrix_s, decisions / best(per_epoch), n_packets / best(per_packet)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=SEED)
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    n_epochs = 500 if args.quick else 2000
    n_packets = 5_000 if args.quick else 20_000
    rng = np.random.default_rng(args.seed)
    dist = rng.uniform(4.0, 16.0, size=(n_epochs, N_LINKS))
    links = np.stack([np.arange(1, N_LINKS + 1), np.arange(2, N_LINKS + 2)], axis=1)
    rows = [
        (name, *measure(stack, name != "bernoulli", args.seed, links, dist, n_packets))
        for name, stack in STACKS.items()
    ]
    base = rows[0]
    print(
        f"seed {args.seed}; {N_LINKS} links x {n_epochs} epochs; per packet {n_packets} decisions"
    )
    print(
        f"{'model':20s} {'matrix /s':>12s} {'ratio':>6s} {'per-epoch /s':>13s} {'ratio':>6s} {'decide /s':>11s} {'ratio':>6s}"
    )
    for name, m, e, p in rows:
        print(
            f"{name:20s} {m:12.3g} {m / base[1]:6.2f} {e:13.3g} {e / base[2]:6.2f} {p:11.3g} {p / base[3]:6.2f}"
        )


if __name__ == "__main__":
    main()
