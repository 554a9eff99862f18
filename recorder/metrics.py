"""What a run measures (docs/model.md §7), from true states the agents never see. Pure numpy."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]


def formation_error(positions: Array, edges: npt.NDArray[np.int64], weights: Array) -> Array:
    """RMS over edges of ``||x_i − x_j|| − C_ij``.

    positions : (..., n, d) [m]; edges : (m, 2) agent ids; weights : (m,) ``C_ij`` [m].
    Returns (...) [m].
    """
    diff = positions[..., edges[:, 0] - 1, :] - positions[..., edges[:, 1] - 1, :]
    gap = np.linalg.norm(diff, axis=-1) - weights
    return np.asarray(np.sqrt(np.mean(gap**2, axis=-1)), dtype=float)


def shape_error(positions: Array, edges: npt.NDArray[np.int64], offsets: Array) -> Array:
    """RMS over edges of ``||(x_i − x_j) − (d0_i − d0_j)||``; shapes as in :func:`formation_error`."""
    i, j = edges[:, 0] - 1, edges[:, 1] - 1
    diff = positions[..., i, :] - positions[..., j, :] - (offsets[i] - offsets[j])
    return np.asarray(np.sqrt(np.mean(np.sum(diff**2, axis=-1), axis=-1)), dtype=float)


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
