"""What a run measures (docs/model.md §7), from true states the agents never see. Pure numpy."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]


def formation_error(
    positions: Array, edges: npt.NDArray[np.int64], weights: Array, on: Mask | None = None
) -> Array:
    """RMS over edges of ``||x_i − x_j|| − C_ij``.

    positions : (..., n, d) [m]; edges : (m, 2) agent ids; weights : (m,) ``C_ij`` [m];
    on : (..., m) the edges counted, broadcast against ``positions``' leading axes (None:
    every edge; with events, the edges between agents taking part). Returns (...) [m],
    NaN where no edge counts.
    """
    diff = positions[..., edges[:, 0] - 1, :] - positions[..., edges[:, 1] - 1, :]
    gap = np.linalg.norm(diff, axis=-1) - weights
    return _rms(gap**2, on)


def shape_error(
    positions: Array, edges: npt.NDArray[np.int64], offsets: Array, on: Mask | None = None
) -> Array:
    """RMS over edges of ``||(x_i − x_j) − (d0_i − d0_j)||``; shapes as in :func:`formation_error`."""
    i, j = edges[:, 0] - 1, edges[:, 1] - 1
    diff = positions[..., i, :] - positions[..., j, :] - (offsets[i] - offsets[j])
    return _rms(np.sum(diff**2, axis=-1), on)


def _rms(sq: Array, on: Mask | None) -> Array:
    """Root mean over the last axis of ``sq`` (..., m), of the entries ``on`` only."""
    if on is None:
        return np.asarray(np.sqrt(_sum_last(sq) / sq.shape[-1]), dtype=float)
    on = np.broadcast_to(on, sq.shape)
    count = on.sum(axis=-1)
    total = _sum_last(np.where(on, sq, 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.asarray(np.where(count > 0, np.sqrt(total / count), np.nan), dtype=float)


def _sum_last(a: Array) -> Array:
    """Sum over the last axis, left to right: the same bits for one epoch as for a batch of
    them (numpy's reduction order depends on the leading shape, so an epoch's error summed
    live by the recorder differed in the last bit from the same epoch read back in a batch)."""
    total = np.zeros(a.shape[:-1])
    for c in range(a.shape[-1]):
        total = total + a[..., c]
    return total


def error_statistics(errors: Array) -> tuple[Array, Array, float]:
    """Mean (d,), covariance (d, d) and covariance trace of error vectors (N, d); NaN when N < 2."""
    d = errors.shape[1] if errors.ndim == 2 else 0
    if errors.shape[0] < 2:
        return np.full(d, np.nan), np.full((d, d), np.nan), float("nan")
    mean = errors.mean(axis=0)
    cov = np.atleast_2d(np.cov(errors, rowvar=False))
    return mean, cov, float(np.trace(cov))


def nees(estimates: Array, covariances: Array, truth: Array, mask: npt.NDArray[np.bool_]) -> Array:
    """Normalised estimation error squared ``(x̂ − x)ᵀ Cov⁻¹ (x̂ − x)`` per masked agent.

    estimates, truth : (n, d) [m]; covariances : (n, d, d) [m²]; mask : (n,) agents to score.
    Returns (mask.sum(),); its mean is ``d`` for an honest estimator (docs/model.md §5).
    """
    err = (estimates - truth)[mask]
    cov = covariances[mask]
    if err.shape[0] == 0:
        return np.zeros(0)
    solved = np.linalg.solve(cov, err[..., None])[..., 0]
    return np.asarray(np.einsum("nd,nd->n", err, solved), dtype=float)


def longest_run(flags: npt.NDArray[np.bool_]) -> int:
    """Length of the longest run of True in a 1-D boolean array (e.g. a link's outage)."""
    if flags.size == 0 or not flags.any():
        return 0
    padded = np.concatenate([[False], flags, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return int(np.max(edges[1::2] - edges[::2]))


def pair_distances(positions: Array) -> Array:
    """Distances between every pair ``i < j`` (``np.triu_indices`` order).

    positions : (..., n, d) [m]. Returns (..., n (n − 1) / 2) [m].
    """
    i, j = np.triu_indices(positions.shape[-2], k=1)
    diff = positions[..., i, :] - positions[..., j, :]
    return np.asarray(np.sqrt(np.sum(diff * diff, axis=-1)), dtype=float)


def min_distance(positions: Array) -> Array:
    """The minimum inter-agent distance per epoch: positions (T, n, d) [m] → (T,) [m] (inf if n < 2)."""
    dist = pair_distances(positions)
    if dist.shape[-1] == 0:
        return np.full(positions.shape[:-2], np.inf)
    return np.asarray(dist.min(axis=-1), dtype=float)


def collisions(
    positions: Array, body_diameter_m: float
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """Collisions per pair: times two bodies ``body_diameter_m`` across come closer than that.

    positions : (T, n, d) [m]. A collision is an epoch in contact after one out of contact
    (or the first epoch): a pair that stays in contact counts once. Returns ``pairs``
    (P, 2) agent ids and ``counts`` (P,), both in ``np.triu_indices`` order; 0 diameter, no counts.
    """
    n = positions.shape[-2]
    i, j = np.triu_indices(n, k=1)
    pairs = np.stack([i + 1, j + 1], axis=1).astype(np.int64)
    if body_diameter_m <= 0.0 or positions.shape[0] == 0:
        return pairs, np.zeros(pairs.shape[0], dtype=np.int64)
    touch = pair_distances(positions) < body_diameter_m  # (T, P)
    starts = touch & ~np.concatenate([np.zeros((1, touch.shape[1]), bool), touch[:-1]], axis=0)
    return pairs, starts.sum(axis=0).astype(np.int64)


def time_out_of_bounds(positions: Array, low_m: Array, high_m: Array, period_s: float) -> Array:
    """Time each agent spends outside the box ``[low_m, high_m]`` (d,) [m]: positions (T, n, d) → (n,) [s]."""
    outside = ((positions < low_m) | (positions > high_m)).any(axis=-1)
    return np.asarray(outside.sum(axis=0) * period_s, dtype=float)
