"""Capacity queues (issue 29): what a queue on every link costs netem, the simulator and the core.

Run ``python -m bench capacity [--quick] [--seed S]``. Three measurements, each against a
baseline measured in the same run:

1. **netem's lockstep forwarding** (the state phase of the paper scenario, as
   ``bench_netem_forward``): forwarded packets/s and netem's CPU per packet with Bernoulli
   0.1 and a ``link`` queue on every formation link (a rate that passes everything: the cost
   of judging, not of losing), against Bernoulli 0.1 alone.
2. **the batched simulator**: cells (member-epochs) per second of a batch of seeds of the
   paper scenario with the access point as a medium of every control link and every agent's
   radio limited, against the same batch without capacity.
3. **the core** (``netem.links.capacity.serve_queue``): packets/s of one queue in virtual time,
   against netem's per-packet Bernoulli decision (``LinkModel.decide``).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from bench.bench_netem_forward import forward_rate
from bench.netem_rig import ROOT
from formation.linkmodels import Bernoulli
from formation.scenario import Scenario
from netem.links.capacity import QueueParams, serve_queue
from netem.links.models import LinkModel
from testbed.sim.batch import plan_batch, run_batch

SEED = 29
LOSSY = [{"model": "bernoulli", "p_loss": 0.1}]


def best(fn: Callable[[], object], repeat: int = 3) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def paper() -> Scenario:
    return Scenario.from_file(ROOT / "scenarios/paper.toml")


def every_link_queued() -> dict[str, Any]:
    links = paper().directed_links.tolist()
    return {
        "formation_default": LOSSY,
        "capacity": [
            {"scope": "link", "link": [a, b], "rate_bps": 1e9, "limit_packets": 64}
            for a, b in links
        ],
    }


def netem_forwarding(epochs: int, repeats: int) -> None:
    """Pairs run in turn, neither always first (the machine is shared); the ratio is of each
    one's best CPU per packet over the pairs, with the median of the pairs' own ratios."""
    print(f"1. netem, {epochs} lockstep epochs of the paper's state phase (seed of the scenario)")
    runs: dict[str, list[tuple[float, float]]] = {"Bernoulli": [], "queued": []}
    for r in range(repeats):
        pair = [("Bernoulli", {"formation_default": LOSSY}), ("queued", every_link_queued())]
        for name, network in pair if r % 2 == 0 else pair[::-1]:
            rate, cpu, _ = forward_rate(False, epochs, network)
            runs[name].append((rate, cpu))
        (base, base_cpu), (rate, cpu) = runs["Bernoulli"][-1], runs["queued"][-1]
        print(
            f"   pair {r + 1}: Bernoulli 0.1 alone {base:8.0f} forwarded/s, {base_cpu:5.2f} µs CPU/packet; "
            f"with a queue on every link {rate:8.0f}/s, {cpu:5.2f} µs/packet; "
            f"ratio rate {rate / base:.2f}, CPU per packet {cpu / base_cpu:.2f}",
            flush=True,
        )
    (base, base_cpu), (rate, cpu) = (
        (max(r for r, _ in runs[n]), min(c for _, c in runs[n])) for n in ("Bernoulli", "queued")
    )
    ratios = [q[1] / b[1] for b, q in zip(runs["Bernoulli"], runs["queued"], strict=True)]
    print(
        f"   best of {repeats}: Bernoulli 0.1 alone {base:8.0f}/s, {base_cpu:5.2f} µs CPU/packet; "
        f"with a queue on every link {rate:8.0f}/s, {cpu:5.2f} µs/packet; ratio rate "
        f"{rate / base:.2f}, CPU per packet {cpu / base_cpu:.2f} (target <= 1.25); "
        f"the pairs' CPU ratios: median {float(np.median(ratios)):.2f}, "
        f"{min(ratios):.2f} to {max(ratios):.2f}",
        flush=True,
    )


def simulator(seed: int, members: int, epochs: int) -> None:
    free = paper().with_overrides(epochs=epochs, network={"formation_default": LOSSY})
    network = {
        "formation_default": LOSSY,
        "capacity": [
            {"scope": "medium", "medium": "ap", "links": "control", "rate_bps": 40_000.0,
             "limit_packets": 8},
            *({"scope": "radio", "agent": i, "rate_bps": 60_000.0, "limit_packets": 4}
              for i in range(1, free.n + 1)),
        ],
    }  # fmt: skip
    capped = free.with_overrides(network=network)
    seeds = list(range(seed, seed + members))

    def cells(s: Scenario) -> float:
        return members * epochs / best(lambda: run_batch(plan_batch(s, seeds), "estimate"))

    base, with_cap = cells(free), cells(capped)
    print(f"2. simulator, paper scenario, {members} seeds from {seed} × {epochs} epochs, estimate")
    print(
        f"   without capacity {base:9.0f} cells/s; with the access point and every radio "
        f"limited {with_cap:9.0f} cells/s; ratio {with_cap / base:.2f}",
        flush=True,
    )


def core(seed: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    arrivals = np.cumsum(rng.exponential(8 * 300 / 1e6, n))  # load 1 of 300 B at 1 Mbit/s
    sizes = np.full(n, 300)
    params = QueueParams(rate_bps=1e6, limit_packets=8)
    queued = n / best(lambda: serve_queue(params, arrivals, sizes))
    model = LinkModel([Bernoulli(p_loss=0.1)], seed, 1, 2)

    def decide() -> None:
        for k in range(n):
            model.decide(k)

    bern = n / best(decide)
    print(f"3. core, {n} Poisson packets at load 1, seed {seed}")
    print(
        f"   Bernoulli LinkModel.decide {bern:10.0f} packets/s; serve_queue() one queue "
        f"{queued:10.0f} packets/s; ratio {queued / bern:.2f}",
        flush=True,
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seed", type=int, default=SEED)
    p.add_argument("--quick", action="store_true", help="fewer epochs and two netem pairs")
    args = p.parse_args()
    quick = args.quick
    core(args.seed, 20_000 if quick else 100_000)
    simulator(args.seed, 20 if quick else 50, 50 if quick else 200)
    netem_forwarding(1_000 if quick else 4_000, 2 if quick else 5)


if __name__ == "__main__":
    main()
