"""Closed forms of the link models: long-run loss rate, burst length, occupancy, delay moments.

The numbers the statistical tests and sweeps check ``netem.models`` against
(MODEL.md §4, §8); pure functions of the specs, no draws.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from formation.linkmodels import (
    Bernoulli,
    Delay,
    Down,
    Duplicate,
    GilbertElliott,
    Markov4,
    Outage,
    Reorder,
    Up,
)
from netem.layers import Floats, _Delay
from netem.stack import LinkModelError

if TYPE_CHECKING:
    from formation.linkmodels import LinkModelSpec


def _loss_chain(spec: LinkModelSpec) -> tuple[Floats, Floats] | None:
    """``(T, loss)`` of a loss layer as a hidden Markov chain started in state 0; None if none."""
    if isinstance(spec, Up | Delay | Duplicate | Reorder):
        return np.ones((1, 1)), np.zeros(1)
    if isinstance(spec, Down):
        return np.ones((1, 1)), np.ones(1)
    if isinstance(spec, Bernoulli) and spec.correlation == 0.0:
        return np.ones((1, 1)), np.array([spec.p_loss])
    if isinstance(spec, GilbertElliott):
        p, r = spec.p, spec.r
        return np.array([[1 - p, p], [r, 1 - r]]), np.array([spec.one_minus_k, spec.one_minus_h])
    if isinstance(spec, Markov4):
        s = spec
        t = np.array(
            [
                [1 - s.p13 - s.p14, 0.0, s.p13, s.p14],
                [0.0, 1 - s.p23, s.p23, 0.0],
                [s.p31, s.p32, 1 - s.p31 - s.p32, 0.0],
                [1.0, 0.0, 0.0, 0.0],
            ]
        )
        return t, np.array([0.0, 0.0, 1.0, 1.0])
    return None


def _cesaro(t: Floats) -> Floats:
    """``lim (1/n) Σ_{k<n} T^k`` by doubling (``n = 2**50``): the long-run occupancy from each state.

    Equals the stationary distribution for an irreducible chain and stays right
    for reducible or periodic ones (e.g. markov4 with ``p13 = 0``). Rows are
    renormalised at each step: repeated squaring would otherwise raise a row sum
    of ``1 - 1e-16`` to the power ``2**50``.
    """
    avg = np.eye(t.shape[0])
    power = t / t.sum(axis=1, keepdims=True)
    for _ in range(50):
        avg = 0.5 * (avg + power @ avg)
        avg /= avg.sum(axis=1, keepdims=True)
        power = power @ power
        power /= power.sum(axis=1, keepdims=True)
    return avg


def stationary_distribution(spec: GilbertElliott | Markov4) -> Floats:
    """Long-run state occupancy of a Gilbert–Elliott ``[good, bad]`` or markov4 ``[π1..π4]`` chain.

    Gilbert–Elliott: ``π_bad = p / (p + r)``. Four-state (Salsano et al. GI
    model, Linux ``loss_4state``): ``π1 = p31 p23 / D``, ``π2 = p13 p32 / D``,
    ``π3 = p13 p23 / D``, ``π4 = p14 p31 p23 / D``, ``D`` their sum. Computed as
    the Cesàro limit from the initial state, so degenerate parameters give the
    occupancy the chain really has.
    """
    chain = _loss_chain(spec)
    assert chain is not None
    return np.array(_cesaro(chain[0])[0], dtype=np.float64)


def _ar1_uniform_cdf(c: float, x: float) -> float:
    """``P(S < x)`` for tc's stationary correlated uniform ``S = (1 - c) Σ_i c^i U_i``.

    Each term ``w U`` is put on a grid of cell ``h = 2**-16`` and the masses are
    convolved with FFTs; terms narrower than a cell enter by their mean. Absolute
    error about ``1e-5``.
    """
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    if c == 0.0 or c >= 1.0:  # c = 1: u keeps its first value, uniform
        return x
    log2h = 16
    h = 2.0**-log2h
    n_fft = 1 << (log2h + 1)
    spectrum = np.ones(n_fft // 2 + 1, dtype=np.complex128)
    offset = -h / 2  # masses are spread over their cells, which accounts for one term's residual
    w = 1.0 - c
    while w >= h:
        cells = math.ceil(w / h)
        cdf = np.minimum(np.arange(cells + 1) * h, w) / w
        spectrum *= np.fft.rfft(np.diff(cdf), n_fft)
        offset += h / 2
        w *= c
    offset += w / (1.0 - c) / 2  # the tail Σ_{i>=M} (1-c) c^i U_i by its mean
    pmf = np.fft.irfft(spectrum, n_fft)
    t = (x - offset) / h
    j = math.floor(t)
    if j < 0:
        return 0.0
    if j >= n_fft:
        return 1.0
    return float(np.sum(pmf[:j]) + (t - j) * pmf[j])


def _layer_loss_rate(spec: LinkModelSpec) -> float:
    if isinstance(spec, Bernoulli) and spec.correlation > 0.0:
        return _ar1_uniform_cdf(spec.correlation, spec.p_loss)
    if isinstance(spec, Outage):
        if spec.start_s is not None or spec.end_s is not None:
            return 1.0 if spec.end_s is None else 0.0
        if spec.end is None:
            return 1.0
        return (spec.end - spec.start) / spec.every if spec.every is not None else 0.0
    chain = _loss_chain(spec)
    assert chain is not None
    t, loss = chain
    return float(_cesaro(t)[0] @ loss)


def _as_stack(specs: LinkModelSpec | Sequence[LinkModelSpec]) -> list[LinkModelSpec]:
    if isinstance(specs, Sequence):
        return list(specs)
    return [specs]


def expected_loss_rate(specs: LinkModelSpec | Sequence[LinkModelSpec]) -> float:
    """Long-run fraction of epochs whose packets are dropped by a stack (or one spec).

    Layers drop independently, so the stack loses ``1 - Π (1 - ρ_l)``. Per layer
    ``ρ``: bernoulli ``p_loss`` (with correlation, the stationary probability that
    tc's correlated uniform is below ``p_loss``, computed numerically);
    Gilbert–Elliott ``π_bad (1-h) + π_good (1-k)``; markov4 ``π3 + π4``; a
    repeating outage ``(end - start) / every``, a one-off window 0 (1 if it never
    ends); delay, duplicate, reorder 0.
    """
    keep = 1.0
    for spec in _as_stack(specs):
        keep *= 1.0 - _layer_loss_rate(spec)
    return 1.0 - keep


def expected_burst_length(specs: LinkModelSpec | Sequence[LinkModelSpec]) -> float:
    """Long-run mean length of runs of consecutive dropped epochs.

    With the stack as a hidden Markov chain (transition ``T``, loss probability
    ``ℓ`` per state, occupancy ``π``): bursts start at rate
    ``Σ_s π_s (1 - ℓ_s) (T ℓ)_s`` and losses occur at rate ``π · ℓ``; the mean
    burst is their ratio (Bernoulli: ``1 / (1 - p)``; Gilbert with ``1-h = 1``,
    ``1-k = 0``: ``1 / r``). ``inf`` when every epoch is lost, ``nan`` when none
    is. Defined for stacks of up, down, bernoulli without correlation,
    gilbert_elliott, markov4, delay, duplicate and reorder.
    """
    t = np.ones((1, 1))
    loss_keep = np.ones(1)
    for i, spec in enumerate(_as_stack(specs)):
        chain = _loss_chain(spec)
        if chain is None:
            raise LinkModelError(
                "closed form", f"stack[{i}] {spec.model} has no closed-form burst length"
            )
        t = np.asarray(np.kron(t, chain[0]), dtype=np.float64)
        loss_keep = np.asarray(np.kron(loss_keep, 1.0 - chain[1]), dtype=np.float64)
    loss = 1.0 - loss_keep
    occupancy = _cesaro(t)[0]
    rate = float(occupancy @ loss)
    starts = float(occupancy @ (loss_keep * (t @ loss)))
    if rate <= 0.0:
        return math.nan
    return math.inf if starts <= 0.0 else rate / starts


class DelayMoments(NamedTuple):
    """Mean and standard deviation of a delay layer's delays, lockstep and realtime."""

    mean_epochs: float
    std_epochs: float
    mean_ms: float
    std_ms: float


def delay_moments(spec: Delay, n_points: int = 1 << 20) -> DelayMoments:
    """Moments of the delays of one uncorrelated delay layer (clipping at 0 and rounding included).

    Lockstep uniform jitter is exact (``2j + 1`` equally likely values: variance
    ``j (j + 1) / 3`` when ``epochs >= j``); the others integrate the delay over
    the uniform draw ``u`` by the midpoint rule on ``n_points`` points. Normal
    jitter has standard deviation ``jitter`` (tables clip at ±4σ); the pareto and
    paretonormal tables have mean and spread of their own, which this measures.
    """
    if spec.correlation > 0.0:
        raise LinkModelError(
            "closed form",
            f"delay correlation = {spec.correlation}; moments are given for correlation 0",
        )
    layer = _Delay(spec, 0)
    u = (np.arange(n_points, dtype=np.float64) + 0.5) / n_points
    de, dms = layer.values(u)
    if spec.distribution == "uniform" and spec.jitter_epochs > 0:
        j = spec.jitter_epochs
        de = np.maximum(spec.epochs + np.arange(-j, j + 1), 0)
    return DelayMoments(float(de.mean()), float(de.std()), float(dms.mean()), float(dms.std()))
