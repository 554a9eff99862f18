"""Relative measurements ``z_ij[k] = x_i[k] − x_j[k] + ε_ij[k]`` (docs/model.md §3, §5)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from formation.keyed_random import Stream, keyed_normal_after, keyed_normal_vector, keyed_state

Array = npt.NDArray[np.float64]


NOISE_BLOCK = 64  # epochs of draws made at once by NoiseKeys


class NoiseKeys:
    """The links ``(i, j)`` of a fixed set, with their draws' shared key prefix hashed once.

    An agent draws its in-links' noise every epoch; :meth:`noise` draws
    :data:`NOISE_BLOCK` epochs in one vectorised pass, since a dozen numpy calls
    per epoch on three links cost an agent process most of its step.
    """

    def __init__(self, seed: int, receivers: Any, senders: Any) -> None:
        r, s = (np.asarray(a, dtype=np.int64)[..., None] for a in (receivers, senders))
        # (..., 1): as keyed_normal_vector expands them, with an axis for the coordinate
        self.state: npt.NDArray[np.uint64] = np.asarray(keyed_state(seed, Stream.NOISE, r, s))
        self._cov: Array | None = None
        self._start = -1
        self._block: Array = np.zeros((0, 0, 0))  # (epoch in block, link, d)

    def noise(self, cov: Array, epoch: int) -> Array:
        """``measurement_noise(cov, seed, receivers, senders, epoch)`` for these links, bit for bit."""
        if cov is not self._cov or not 0 <= epoch - self._start < NOISE_BLOCK:
            self._cov, self._start = cov, epoch
            epochs = np.arange(epoch, epoch + NOISE_BLOCK, dtype=np.int64)
            links = self.state.shape[:-1]
            block = _correlate(
                cov,
                lambda: keyed_normal_after(
                    self.state[..., None, :],
                    epochs[:, None],
                    np.arange(cov.shape[0], dtype=np.int64),
                ),
                (*links, NOISE_BLOCK),
            )
            self._block = np.ascontiguousarray(np.moveaxis(block, -2, 0))
        row: Array = self._block[epoch - self._start]
        return row


def _correlate(cov: Array, standard: Callable[[], Array], shape: tuple[int, ...]) -> Array:
    """``L·std`` with ``L L^T = cov`` for standard normal draws ``standard()`` of ``shape + (d,)``."""
    d = cov.shape[0]
    if not np.any(cov):
        return np.zeros((*shape, d))
    chol = np.linalg.cholesky(cov)
    std = standard().reshape(*shape, d)
    # Elementwise, not a matrix product: BLAS kernels differ with batch size, and one agent
    # must get the same last bit as the whole team in the simulator.
    # A zero factor adds ±0.0 to a sum begun at +0.0: the sum's bits unchanged, so it is skipped.
    out = np.zeros((*shape, d))
    for b in range(d):
        for c in np.flatnonzero(chol[:, b]).tolist():
            out[..., c] += std[..., b] * chol[c, b]
    return out


def measurement_noise(
    cov: Array, seed: int, receivers: Any, senders: Any, epoch: Any, keys: NoiseKeys | None = None
) -> Array:
    """``ε_ij[k] ~ N(0, P)`` keyed by ``(seed, NOISE, i, j, k)``.

    cov : (d, d) ``P_ij`` [m²]; receivers ``i``, senders ``j`` and ``epoch`` broadcast together.
    keys : the same seed and links, prehashed (then ``epoch`` must be one int).
    Returns (..., d) [m]; the same numbers in every process that asks.
    """
    if keys is not None:
        return keys.noise(cov, int(epoch))  # (L, d): the keys' links are receivers × senders
    shape = np.broadcast_shapes(np.shape(receivers), np.shape(senders), np.shape(epoch))
    return _correlate(
        cov,
        lambda: keyed_normal_vector(cov.shape[0], seed, Stream.NOISE, receivers, senders, epoch),
        shape,
    )


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
