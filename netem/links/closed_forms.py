"""Closed forms of the link models: long-run loss rate, burst length, occupancy, delay moments.

The numbers the statistical tests and sweeps check ``netem.links.models`` against
(docs/model.md §4, §8); pure functions of the specs, no draws. Each model gives its
own pieces (``Layer.loss_chain``, ``Layer.loss_rate``, in ``netem.links.linkmodels``);
this module combines them over a stack.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from formation.errors import LinkModelError
from formation.linkmodels import GilbertElliott, LinkModelSpec, Markov4
from netem.links.chains import cesaro
from netem.links.layer import Floats, Layer
from netem.links.linkmodels import layer_of
from netem.links.linkmodels.delay import DelayMoments, delay_moments


def _layer(spec: LinkModelSpec) -> Layer[Any]:
    cls = layer_of(spec)
    if cls is None:
        raise LinkModelError("closed form", f"{spec!r}; expected a LinkModelSpec")
    return cls(spec, 0)


def stationary_distribution(spec: GilbertElliott | Markov4) -> Floats:
    """Long-run state occupancy of a Gilbert–Elliott ``[good, bad]`` or markov4 ``[π1..π4]`` chain.

    Gilbert–Elliott: ``π_bad = p / (p + r)``. Four-state (Salsano et al. GI
    model, Linux ``loss_4state``): ``π1 = p31 p23 / D``, ``π2 = p13 p32 / D``,
    ``π3 = p13 p23 / D``, ``π4 = p14 p31 p23 / D``, ``D`` their sum. Computed as
    the Cesàro limit from the initial state, so degenerate parameters give the
    occupancy the chain really has.
    """
    chain = _layer(spec).loss_chain()
    if chain is None:
        raise LinkModelError("closed form", f"{spec.model} has no state chain")
    return np.array(cesaro(chain[0])[0], dtype=np.float64)


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
        keep *= 1.0 - _layer(spec).loss_rate()
    return 1.0 - keep


def expected_delivery_at(
    specs: LinkModelSpec | Sequence[LinkModelSpec], distance_m: npt.ArrayLike
) -> Floats:
    """Long-run fraction of epochs delivered by a stack on a link ``distance_m`` long [m].

    Layers drop independently: ``Π_r P_r(d) · Π_l (1 − ρ_l)``, with ``P_r(d)`` each
    distance layer's delivery at ``d`` (range ``1[d ≤ max_range_m]``; logistic
    ``1 / (1 + exp((d − d50_m) / width_m))``; log_distance ``Φ(m(d) / σ)``, see
    ``netem/links/linkmodels/log_distance.py``) and ``ρ_l`` every other layer's loss rate
    (:func:`expected_loss_rate`). ``distance_m`` any shape; the result has its shape.
    """
    d = np.asarray(distance_m, dtype=np.float64)
    keep = np.ones(d.shape, dtype=np.float64)
    for spec in _as_stack(specs):
        layer = _layer(spec)
        keep = keep * (layer.delivery_at(d) if layer.ranged else 1.0 - layer.loss_rate())
    return keep


def expected_burst_length(specs: LinkModelSpec | Sequence[LinkModelSpec]) -> float:
    """Long-run mean length of runs of consecutive dropped epochs.

    With the stack as a hidden Markov chain (transition ``T``, loss probability
    ``ℓ`` per state, occupancy ``π``): bursts start at rate
    ``Σ_s π_s (1 - ℓ_s) (T ℓ)_s`` and losses occur at rate ``π · ℓ``; the mean
    burst is their ratio (Bernoulli: ``1 / (1 - p)``; Gilbert with ``1-h = 1``,
    ``1-k = 0``: ``1 / r``). ``inf`` when every epoch is lost, ``nan`` when none
    is. Defined for stacks whose layers all have a ``loss_chain``: up, down,
    bernoulli without correlation, gilbert_elliott, markov4, delay, duplicate
    and reorder.
    """
    t = np.ones((1, 1))
    loss_keep = np.ones(1)
    for i, spec in enumerate(_as_stack(specs)):
        chain = _layer(spec).loss_chain()
        if chain is None:
            raise LinkModelError(
                "closed form", f"stack[{i}] {spec.model} has no closed-form burst length"
            )
        t = np.asarray(np.kron(t, chain[0]), dtype=np.float64)
        loss_keep = np.asarray(np.kron(loss_keep, 1.0 - chain[1]), dtype=np.float64)
    loss = 1.0 - loss_keep
    occupancy = cesaro(t)[0]
    rate = float(occupancy @ loss)
    starts = float(occupancy @ (loss_keep * (t @ loss)))
    if rate <= 0.0:
        return math.nan
    return math.inf if starts <= 0.0 else rate / starts


__all__ = [
    "DelayMoments",
    "delay_moments",
    "expected_burst_length",
    "expected_delivery_at",
    "expected_loss_rate",
    "stationary_distribution",
]
