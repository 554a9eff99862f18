"""Relative measurements ``z_ij[k] = x_i[k] − x_j[k] + ε_ij[k]`` (MODEL.md §3, §5)."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from formation.keyed_random import Stream, keyed_normal_vector

Array = npt.NDArray[np.float64]


def measurement_noise(cov: Array, seed: int, receivers: Any, senders: Any, epoch: Any) -> Array:
    """``ε_ij[k] ~ N(0, P)`` keyed by ``(seed, NOISE, i, j, k)``.

    cov : (d, d) ``P_ij`` [m²]; receivers ``i``, senders ``j`` and ``epoch`` broadcast together.
    Returns (..., d) [m]; the same numbers in every process that asks.
    """
    d = cov.shape[0]
    shape = np.broadcast_shapes(np.shape(receivers), np.shape(senders), np.shape(epoch))
    if not np.any(cov):
        return np.zeros((*shape, d))
    chol = np.linalg.cholesky(cov)
    std = keyed_normal_vector(d, seed, Stream.NOISE, receivers, senders, epoch).reshape(*shape, d)
    # Elementwise, not a matrix product: BLAS kernels differ with batch size, and one agent
    # must get the same last bit as the whole team in the simulator.
    out = np.zeros((*shape, d))
    for b in range(d):
        out += std[..., b : b + 1] * chol[:, b]
    return out


def relative_measurement(
    x_receiver: Array,
    x_sender: Array,
    cov: Array,
    seed: int,
    receivers: Any,
    senders: Any,
    epoch: int,
) -> Array:
    """``z_ij = x_i − x_j + ε_ij``: (L, d) [m] for receivers ``i`` and senders ``j``."""
    return x_receiver - x_sender + measurement_noise(cov, seed, receivers, senders, epoch)
