"""The BLUE of a small team by one dense solve, for a batch of runs at once (docs/model.md §5).

With one noise covariance ``P`` for every measurement, ``A = L ⊗ P⁻¹`` where
``L = Σ_q h_q h_qᵀ`` is the grounded Laplacian counting measurements (an edge
measured both ways counts twice), so with ``u = x − x_r``::

    û_b = L⁻¹ Σ_q h_q z_qᵀ,    Cov(x̂_v) = (L⁻¹)_vv P

whatever ``P`` is. For a team of a few dozen agents one batched LAPACK solve over
``(B, n − 1, n − 1)`` costs less than building any sparse structure (the
simulator's sweeps run hundreds of such teams per epoch; ``bench/bench_sweep.py``);
larger teams take the tree and sparse solvers of ``leader.estimation``. Each run's
system is assembled and solved on its own, so a run gets the same floats in any
batch, alone included.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = ["DENSE_MAX_AGENTS", "dense_blue"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

DENSE_MAX_AGENTS = 32
"""Teams up to this size are solved densely by the leader's epoch (``leader.epoch``)."""


def dense_blue(
    size: int,
    n: int,
    member: IntArray,
    e: IntArray,
    z: FloatArray,
    p: FloatArray,
    r: int,
    x_r: FloatArray,
    covariances: bool,
    observable: BoolArray | None = None,
) -> tuple[FloatArray, FloatArray | None, BoolArray]:
    """BLUE of ``size`` runs of ``n`` agents with one noise covariance ``P``.

    Parameters
    ----------
    size, n : int
        Runs in the batch, agents per run.
    member : (k,) int array
        The run of each used measurement.
    e : (k, 2) int array
        Its pair ``(i, j)``, 0-based agents of that run.
    z : (k, d) float array [m]
        ``z[q] = x_i − x_j + ε``.
    p : (d, d) float array [m²]
        ``P``, the same for every measurement.
    r : int
        The reference, 0-based; ``x_r`` (d,) its position [m].
    covariances : bool
        Whether to return the covariance blocks.
    observable : (size, n) bool array, optional
        The agents joined to the reference by used measurements, if known.

    Returns
    -------
    positions : (size, n, d) [m], NaN where unobservable
    covariances : (size, n, d, d) [m²] or None; zero for the reference
    observable : (size, n) agents joined to the reference by used measurements
    """
    d = z.shape[1]
    i, j = member * n + e[:, 0], member * n + e[:, 1]
    ones = np.ones(i.size)
    # bincount, not matmul: a threaded BLAS call on these small arrays only spins (measured)
    lap = np.bincount(
        np.concatenate([i * n + e[:, 0], j * n + e[:, 1], i * n + e[:, 1], j * n + e[:, 0]]),
        np.concatenate([ones, ones, -ones, -ones]),
        size * n * n,
    ).reshape(size, n, n)  # Σ_q h_q h_qᵀ, h_q = +1 at i, −1 at j
    both = np.concatenate([i, j])
    rhs = np.stack(
        [np.bincount(both, np.concatenate([z[:, a], -z[:, a]]), size * n) for a in range(d)],
        axis=1,
    ).reshape(size, n, d)  # Σ_q h_q z_qᵀ
    if observable is None:
        observable = np.zeros((size, n), dtype=bool)
        observable[:, r] = True
        linked = lap < 0
        while True:  # reach from the reference, one hop a round
            grown = observable | (linked & observable[:, None, :]).any(axis=2)
            if np.array_equal(grown, observable):
                break
            observable = grown
    positions = np.full((size, n, d), np.nan)
    positions[:, r] = x_r
    blocks = None
    if covariances:
        blocks = np.full((size, n, d, d), np.nan)
        blocks[:, r] = 0.0
    if n == 1:
        return positions, blocks, observable
    keep = np.arange(n) != r
    grounded = lap[:, keep][:, :, keep]
    # Agents off the reference's component have no estimate: an identity row keeps the
    # system regular and their rows are discarded.
    off = ~observable[:, keep]
    idx = np.arange(n - 1)
    grounded[:, idx, idx] += off
    solved = np.linalg.solve(grounded, rhs[:, keep])
    positions[:, keep] = x_r + np.where(off[:, :, None], np.nan, solved)
    if blocks is not None:
        diag = np.where(off, np.nan, np.linalg.inv(grounded)[:, idx, idx])
        blocks[:, keep] = diag[:, :, None, None] * p
    return positions, blocks, observable
