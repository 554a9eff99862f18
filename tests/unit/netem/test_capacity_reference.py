"""``netem rate`` queues (``burst_bytes = 0``) against their closed forms, with arrivals spread
in time, for both policies and both limits (docs/model.md §9).

This kernel has no ``netem`` qdisc, so these queues are held to the formulas instead: each
packet is on the wire for ``8 s / r`` after the one before, ``d_k = max(a_k, d_{k-1}) + 8 s_k
/ r`` over the packets kept; an arrival finds waiting the kept packets with ``d_j > a_k``
(the one on the wire included) and is refused (``tail``) or pushes out the oldest of them
not on the wire (``oldest``) while they and it exceed the limit, the packets behind it
then each ``8 s / r`` after the one before. ``oldest`` with ``limit_bytes`` has no kernel
counterpart either (``pfifo_head_drop`` counts packets): it is checked here.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from netem.links.capacity import Policy, QueueParams, serve_queue

RATE = 2e6  # [bit/s]
L = 1000  # [B] a full-size packet


def patterns(seed: int) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Arrival times [s] and sizes [B]: overload, on/off bursts, Poisson at 0.9, trains."""
    rng = np.random.default_rng(seed)
    service = 8 * L / RATE
    n = 300
    sizes = rng.integers(200, 1400, n)
    return {
        "overload": (np.cumsum(rng.exponential(service * 0.8 / 1.5, n)), sizes),
        "on/off": (np.repeat(np.arange(n // 12) * 0.05, 12), sizes[: n // 12 * 12]),
        "poisson 0.9": (np.cumsum(rng.exponential(sizes * 8 / RATE / 0.9)), sizes),
        "trains": (
            np.concatenate([t + 0.001 * np.arange(8) for t in np.cumsum(rng.uniform(0.018, 0.05, n // 8))]),
            np.full(n // 8 * 8, L),
        ),
    }  # fmt: skip


def closed_form(
    arrivals: np.ndarray, sizes: np.ndarray, policy: Policy, limit: tuple[str, int]
) -> np.ndarray:
    """Departures [s] (NaN: dropped) by the formulas of the module's docstring."""
    rate = RATE / 8.0
    kind, bound = limit
    departure = np.full(arrivals.size, np.nan)
    kept: list[int] = []  # in the queue, in order
    for k, (a, s) in enumerate(zip(arrivals.tolist(), sizes.tolist(), strict=True)):
        kept = [j for j in kept if departure[j] > a]

        def full(extra: int, waiting: list[int]) -> bool:
            if kind == "limit_packets":
                return len(waiting) + 1 > bound
            return sum(int(sizes[j]) for j in waiting) + extra > bound

        while policy == "oldest" and full(s, kept):
            on_wire = bool(kept) and departure[kept[0]] - sizes[kept[0]] / rate <= a
            movable = kept[1:] if on_wire else kept
            if not movable:
                break
            departure[movable[0]] = math.nan
            kept.remove(movable[0])
            last = departure[kept[0]] if on_wire else -math.inf  # Lindley from the wire on
            for j in kept[1:] if on_wire else kept:
                last = departure[j] = max(float(arrivals[j]), last) + sizes[j] / rate
        if full(s, kept):
            continue
        start = max(a, departure[kept[-1]]) if kept else a
        departure[k] = start + s / rate
        kept.append(k)
    return departure


@pytest.mark.parametrize("policy", ["tail", "oldest"])
@pytest.mark.parametrize("limit", [("limit_packets", 5), ("limit_bytes", 6000)])
@pytest.mark.parametrize("pattern", ["overload", "on/off", "poisson 0.9", "trains"])
def test_netem_rate_departs_and_drops_as_its_closed_form(
    policy: Policy, limit: tuple[str, int], pattern: str, seed: int
) -> None:
    arrivals, sizes = patterns(seed)[pattern]
    params = QueueParams(RATE, policy=policy, **{limit[0]: limit[1]})  # type: ignore[arg-type]
    run = serve_queue(params, arrivals, sizes)
    want = closed_form(arrivals, sizes, policy, limit)
    np.testing.assert_array_equal(np.isnan(run.departure_s), np.isnan(want))
    np.testing.assert_allclose(run.departure_s, want, rtol=1e-12, atol=0.0)
    assert 0 < np.isnan(want).sum() < arrivals.size  # the pattern fills the queue
