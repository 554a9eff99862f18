"""What a run measures (docs/model.md §7), from true states the agents never see. Pure numpy."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

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
    """Mean (d,), covariance (d, d) and covariance trace of error vectors (N, d); NaN when N < 2.

    The rows are summed in one canonical order (sorted by their coordinates), so a recording
    and the simulator, which list the same rows in different orders, agree to the last bit.
    """
    d = errors.shape[1] if errors.ndim == 2 else 0
    if errors.shape[0] < 2:
        return np.full(d, np.nan), np.full((d, d), np.nan), float("nan")
    errors = errors[np.lexsort(errors.T[::-1])]
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
    """The minimum inter-agent distance per epoch: positions (T, n, d) [m] → (T,) [m].

    Agents with a non-finite position (not recorded) are left out of their epoch; inf if
    ``n < 2``, NaN for an epoch with fewer than two agents recorded. Nearest neighbours
    by k-d tree, ``O(n log n)`` an epoch, the distance itself as :func:`pair_distances`.
    """
    out: Array = np.full(positions.shape[0], np.inf if positions.shape[-2] < 2 else np.nan)
    for t in range(positions.shape[0]) if positions.shape[-2] >= 2 else ():
        points = positions[t][np.isfinite(positions[t]).all(axis=-1)]
        if points.shape[0] >= 2:
            _, nearest = cKDTree(points).query(points, k=2)
            diff = points - points[nearest[:, 1]]
            out[t] = np.sqrt(np.sum(diff * diff, axis=-1)).min()
    return out


def contacts(positions: Array, distance_m: float) -> npt.NDArray[np.int64]:
    """Pairs closer than ``distance_m`` in one epoch: positions (n, d) → (P, 2) 0-based, ``i < j``.

    Non-finite positions are never in contact. In ``np.triu_indices`` order.
    """
    seen = np.flatnonzero(np.isfinite(positions).all(axis=-1))
    if seen.shape[0] < 2:
        return np.zeros((0, 2), dtype=np.int64)
    near = cKDTree(positions[seen]).query_pairs(distance_m, output_type="ndarray")
    pairs = np.sort(seen[near], axis=1).astype(np.int64)
    diff = positions[pairs[:, 0]] - positions[pairs[:, 1]]
    pairs = pairs[np.sqrt(np.sum(diff * diff, axis=-1)) < distance_m]
    ordered: npt.NDArray[np.int64] = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    return ordered


def collisions(
    positions: Array, body_diameter_m: float
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """Collisions per pair: times two bodies ``body_diameter_m`` across come closer than that.

    positions : (T, n, d) [m], non-finite where not recorded (never in contact). A collision
    is an epoch in contact after one out of contact (or the first epoch): a pair that stays
    in contact counts once. Returns the pairs that collided, ``pairs`` (P, 2) agent ids in
    ``np.triu_indices`` order, and their ``counts`` (P,); 0 diameter, none.
    """
    n = positions.shape[-2]
    none = np.zeros((0, 2), dtype=np.int64), np.zeros(0, dtype=np.int64)
    if body_diameter_m <= 0.0 or positions.shape[0] == 0:
        return none
    before = np.zeros(0, dtype=np.int64)
    starts = []
    for t in range(positions.shape[0]):
        touching = contacts(positions[t], body_diameter_m)
        code = touching[:, 0] * n + touching[:, 1]
        starts.append(code[~np.isin(code, before)])
        before = code
    codes, counts = np.unique(np.concatenate(starts), return_counts=True)
    if codes.shape[0] == 0:
        return none
    pairs = np.stack([codes // n + 1, codes % n + 1], axis=1).astype(np.int64)
    return pairs, counts.astype(np.int64)


def time_out_of_bounds(positions: Array, low_m: Array, high_m: Array, period_s: float) -> Array:
    """Time each agent spends outside the box ``[low_m, high_m]`` (d,) [m]: positions (T, n, d) → (n,) [s]."""
    outside = ((positions < low_m) | (positions > high_m)).any(axis=-1)
    return np.asarray(outside.sum(axis=0) * period_s, dtype=float)


def consistency(
    positions: Array, estimates: Array, covariances: Array, scored: Mask
) -> tuple[Array, Array]:
    """NEES values and estimation errors ``x̂ − x`` of the scored agents, epoch by epoch.

    positions : (P, n, d) true [m]; estimates : (E, n, d) [m]; covariances : (E, n, d, d)
    [m²]; scored : (E, n) the agents to score (observable followers). An agent whose truth,
    estimate or covariance is unknown, or whose covariance is singular (ideal sensors), is
    left out. Returns (M,) and (M, d).
    """
    d = estimates.shape[-1]
    values, errors = [], []
    for k in range(min(len(positions), len(estimates))):
        truth = positions[k]
        mask = scored[k] & np.isfinite(truth).all(axis=1)
        mask &= np.isfinite(estimates[k]).all(axis=1)
        mask &= np.abs(np.linalg.det(np.nan_to_num(covariances[k]))) > 0
        if mask.any():
            values.append(nees(estimates[k], covariances[k], truth, mask))
            errors.append(estimates[k][mask] - truth[mask])
    nees_values = np.concatenate(values) if values else np.zeros(0)
    return nees_values, np.concatenate(errors) if errors else np.zeros((0, d))
