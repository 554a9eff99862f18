"""Relative measurements ``z_ij[k] = x_i[k] − x_j[k] + ε_ij[k]`` (MODEL.md §3, §5)."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from formation.keyed_random import Stream, keyed_normal_after, keyed_normal_vector, keyed_state

Array = npt.NDArray[np.float64]


class NoiseKeys:
    """The links ``(i, j)`` of a fixed set, with their draws' shared key prefix hashed once:
    an agent draws its in-links' noise every epoch."""

    def __init__(self, seed: int, receivers: Any, senders: Any) -> None:
        r, s = (np.asarray(a, dtype=np.int64)[..., None] for a in (receivers, senders))
        self.state = keyed_state(seed, Stream.NOISE, r, s)  # as keyed_normal_vector expands them


def measurement_noise(
    cov: Array, seed: int, receivers: Any, senders: Any, epoch: Any, keys: NoiseKeys | None = None
) -> Array:
    """``ε_ij[k] ~ N(0, P)`` keyed by ``(seed, NOISE, i, j, k)``.

    cov : (d, d) ``P_ij`` [m²]; receivers ``i``, senders ``j`` and ``epoch`` broadcast together.
    keys : the same seed and links, prehashed (then ``epoch`` must be one int).
    Returns (..., d) [m]; the same numbers in every process that asks.
    """
    d = cov.shape[0]
    shape = np.broadcast_shapes(np.shape(receivers), np.shape(senders), np.shape(epoch))
    if not np.any(cov):
        return np.zeros((*shape, d))
    chol = np.linalg.cholesky(cov)
    if keys is not None:
        coord = np.arange(d, dtype=np.int64)
        std = keyed_normal_after(keys.state, int(epoch), coord).reshape(*shape, d)
    else:
        std = keyed_normal_vector(d, seed, Stream.NOISE, receivers, senders, epoch).reshape(
            *shape, d
        )
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
    keys: NoiseKeys | None = None,
) -> Array:
    """``z_ij = x_i − x_j + ε_ij``: (L, d) [m] for receivers ``i`` and senders ``j``."""
    return x_receiver - x_sender + measurement_noise(cov, seed, receivers, senders, epoch, keys)
