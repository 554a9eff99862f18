"""``delay``: per-packet delay with jitter (tc ``delay TIME JITTER CORR distribution DIST``).

Lockstep ``delay_epochs = max(0, epochs + J)``, with ``J`` uniform on the
integers ``-j..j`` (``distribution = "uniform"``) or ``round(j * Z)``; realtime
``delay_ms = max(0, ms + jitter_ms * Z)``, with ``Z = 2u - 1`` (uniform) or the
continuous inverse of tc's tables (normal; pareto with shape 3, centred and
scaled by 4/3; paretonormal = (normal + 3 pareto) / 4 on one quantile), clipped
to the tables' int16 range. Correlation ``c`` runs tc's correlated uniform over
epochs (packets with ``seq > 0`` use ``(1 - c) fresh + c u[k-1]``). Several delay
layers add up. Delays are drawn per packet, keyed by ``(epoch, seq)``.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt
from scipy.special import ndtri

from formation.errors import LinkModelError
from formation.keyed_random import Stream
from formation.linkmodels import Delay
from netem.links.chains import run_ar1
from netem.links.layer import Floats, Ints, Keys, Layer, LayerOutput, lossless

_TABLE_MAX = 32767 / 8192  # tc's distribution tables are int16 scaled by NETEM_DIST_SCALE
_TABLE_MIN = -32768 / 8192


def table_variate(distribution: str, u: Floats) -> Floats:
    """Standardised delay variate ``Z(u)`` of tc netem's distribution tables (iproute2 ``netem/``)."""
    if distribution == "uniform":
        return 2.0 * u - 1.0
    normal = np.asarray(ndtri(u), dtype=np.float64)
    if distribution == "normal":
        return np.clip(normal, _TABLE_MIN, _TABLE_MAX)
    # pareto.c: shape a = 3, x = (1 - q)^(-1/3) has mean 1.5; the table holds (x - 1.5) * 4/3
    pareto = np.minimum((4.0 / 3.0) * (1.0 / np.cbrt(1.0 - u) - 1.5), _TABLE_MAX)
    if distribution == "pareto":
        return pareto
    # paretonormal.c: (normal + 3 pareto) / 4 on the same quantile, normal tabulated on [-10, 10]
    return np.clip((np.clip(normal, -10.0, 10.0) + 3.0 * pareto) / 4.0, _TABLE_MIN, _TABLE_MAX)


class DelayLayer(Layer[Delay]):
    def __init__(self, spec: Delay, occurrence: int) -> None:
        super().__init__(spec, occurrence)
        self.stateful = spec.correlation > 0.0

    def values(self, u: Floats) -> tuple[Ints, Floats]:
        """Delays from (correlated) uniforms ``u``: ``[epochs]`` and ``[ms]``."""
        d = self.spec
        if d.jitter_epochs == 0:
            epochs = np.full(u.shape, d.epochs, dtype=np.int64)
        elif d.distribution == "uniform":
            j = d.jitter_epochs
            jitter = np.floor(u * (2 * j + 1)).astype(np.int64) - j
            epochs = np.maximum(d.epochs + jitter, 0)
        else:
            jitter = np.rint(d.jitter_epochs * table_variate(d.distribution, u)).astype(np.int64)
            epochs = np.maximum(d.epochs + jitter, 0)
        if d.jitter_ms == 0.0:
            ms = np.full(u.shape, d.ms, dtype=np.float64)
        else:
            ms = np.maximum(d.ms + d.jitter_ms * table_variate(d.distribution, u), 0.0)
        return epochs, ms

    def fresh(self, keys: Keys, epochs: Ints, seq: int) -> Floats:
        return keys.uniform(Stream.DELAY, self.kind, self.occ, epochs, seq, 0)

    def run(
        self, keys: Keys, epochs: Ints, carry: npt.NDArray[Any] | None
    ) -> tuple[LayerOutput, Any]:
        x = self.fresh(keys, epochs, 0)
        if not self.stateful:
            de, dms = self.values(x)
            return LayerOutput(delay_epochs=de, delay_ms=dms), None
        c = self.spec.correlation
        if carry is None:
            zero = np.zeros(1, np.int64)
            carry = keys.uniform(Stream.DELAY, self.kind, self.occ, zero, 0, 1)[:, 0]
        y = run_ar1(1.0 - c, c, x, carry)
        prev = np.concatenate([carry[:, None], y[:, :-1]], axis=1)
        de, dms = self.values(y)
        return LayerOutput(delay_epochs=de, delay_ms=dms, chain_prev=prev), y[:, -1]

    def packet(self, keys: Keys, epochs: Ints, seq: int, prev: Floats | None) -> LayerOutput:
        u = self.fresh(keys, epochs, seq)
        if self.stateful and prev is not None:
            c = self.spec.correlation
            u = (1.0 - c) * u + c * prev
        de, dms = self.values(u)
        return LayerOutput(delay_epochs=de, delay_ms=dms)

    def loss_chain(self) -> tuple[Floats, Floats]:
        return lossless()


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
    layer = DelayLayer(spec, 0)
    u = (np.arange(n_points, dtype=np.float64) + 0.5) / n_points
    de, dms = layer.values(u)
    if spec.distribution == "uniform" and spec.jitter_epochs > 0:
        j = spec.jitter_epochs
        de = np.maximum(spec.epochs + np.arange(-j, j + 1), 0)
    return DelayMoments(float(de.mean()), float(de.std()), float(dms.mean()), float(dms.std()))


LAYER = DelayLayer

__all__ = ["LAYER", "DelayLayer", "DelayMoments", "delay_moments", "table_variate"]
