"""The rigidity matrix of a framework and its rank (docs/model.md §2).

The rank is the dense SVD's, every singular value above :data:`RANK_RTOL` of the largest
counted; the checks that scale to large frameworks (:mod:`formation.rigidity_check`) use
the same tolerance. The scenario loader checks its shape with them; the leader re-exports
them (``leader.rigidity``).
"""

from __future__ import annotations

import operator

import numpy as np
import numpy.typing as npt
from scipy.sparse import csr_matrix
from scipy.sparse.linalg import eigsh

from formation.errors import GraphInputError
from formation.graph import FloatArray, IntArray, as_edge_array, as_positions, check_agent_count

RANK_RTOL = 1e-9
"""Singular values at most this fraction of the largest one count as zero (docs/model.md §2)."""


def rigidity_matrix(positions: npt.ArrayLike, edges: npt.ArrayLike) -> FloatArray:
    """Rigidity matrix ``R(q)`` of a framework (docs/model.md §2).

    Parameters
    ----------
    positions : (n, d) array_like [m]
        Row ``i − 1`` is agent ``i``.
    edges : (m, 2) array_like of int
        Agent ids ``1..n``.

    Returns
    -------
    R : (m, n·d) float64 array
        Row ``e`` of edge ``{i, j}`` holds ``(x_i − x_j)ᵀ`` in columns ``(i−1)d … id − 1``,
        ``(x_j − x_i)ᵀ`` in agent ``j``'s block and zeros elsewhere, so that
        ``R q̇`` is half the rate of change of the squared edge lengths.
    """
    x = as_positions(positions)
    n, d = x.shape
    e = as_edge_array(n, edges) - 1
    m = e.shape[0]
    diff = x[e[:, 0]] - x[e[:, 1]]
    r = np.zeros((m, n * d))
    rows = np.arange(m)[:, None]
    cols = np.arange(d)[None, :]
    r[rows, e[:, 0:1] * d + cols] = diff
    r[rows, e[:, 1:2] * d + cols] = -diff
    return r


def rigidity_rank(positions: npt.ArrayLike, edges: npt.ArrayLike) -> int:
    """Rank of the rigidity matrix by SVD, singular values ``> 1e-9 · σ_max`` counted (docs/model.md §2).

    The SVD is dense, ``O(min(m, nd)² · max(m, nd))``: fine for formations of a
    few hundred agents, not for thousands.

    Parameters
    ----------
    positions : (n, d) array_like [m]
        Row ``i − 1`` is agent ``i``.
    edges : (m, 2) array_like of int
        Agent ids ``1..n``.
    """
    return _svd_rank(rigidity_matrix(positions, edges))


def _svd_rank(r: FloatArray) -> int:
    """Singular values of ``r`` above ``RANK_RTOL · σ_max``, counted."""
    if r.shape[0] == 0 or r.shape[1] == 0:
        return 0
    s = np.linalg.svd(r, compute_uv=False)
    if s[0] == 0.0:
        return 0  # every edge joins coincident points
    return int(np.count_nonzero(s > RANK_RTOL * s[0]))


def expected_rigidity_rank(n: int, d: int) -> int:
    """Rank of the rigidity matrix of an infinitesimally rigid framework of ``n`` agents in ``R^d``.

    ``n·d − d(d+1)/2`` (``2n − 3`` in the plane, ``3n − 6`` in space) once
    ``n > d``; ``n(n−1)/2`` for ``n ≤ d + 1`` (every pair an edge: the
    **[fix]** of docs/model.md §2 for ``n < 3`` in 3-D). Both agree at ``n = d + 1``.
    """
    count = check_agent_count(n)
    dim = operator.index(d)
    if dim < 1:
        raise GraphInputError(f"d = {dim}", "a dimension of at least 1")
    if count <= dim + 1:
        return count * (count - 1) // 2
    return count * dim - dim * (dim + 1) // 2


SVD_MAX_COLUMNS = 600
"""Frameworks of at most this many coordinates ``n·d`` are checked by the dense SVD, larger
ones by the vertex-addition certificate and the pinned stiffness (docs/model.md §2)."""


def sparse_rigidity_matrix(positions: npt.ArrayLike, edges: npt.ArrayLike) -> csr_matrix:
    """:func:`rigidity_matrix` as a sparse matrix, ``2d`` entries per row."""
    x = as_positions(positions)
    n, d = x.shape
    e = as_edge_array(n, edges) - 1
    m = e.shape[0]
    diff = x[e[:, 0]] - x[e[:, 1]]
    cols = np.concatenate([e[:, :1] * d + np.arange(d), e[:, 1:] * d + np.arange(d)], axis=1)
    vals = np.concatenate([diff, -diff], axis=1)
    return csr_matrix((vals.ravel(), (np.repeat(np.arange(m), 2 * d), cols.ravel())), (m, n * d))


def distance_epsilon_bound(positions: npt.ArrayLike, edges: npt.ArrayLike, pinned: int) -> float:
    """The step ``ε`` below which the distance law holds the shape: ``1 / λ_max(RᵀR)_F``.

    The followers' law is gradient descent on ``V = ¼ Σ (||x_i − x_j||² − C_ij²)²`` with step
    ``ε``, the reference agent ``pinned`` to its trajectory. At the shape the Hessian is
    ``2 RᵀR`` (``R`` at the offsets); ``(RᵀR)_F`` keeps the followers' rows and columns. The
    step's linearisation ``I − 2ε (RᵀR)_F`` is stable iff ``ε < 1 / λ_max((RᵀR)_F)``
    (docs/model.md §3). A lost edge only removes a term from ``RᵀR``, so the bound holds for
    every healthy subgraph.

    Parameters
    ----------
    positions : (n, d) array_like [m], the shape
    edges : (m, 2) array_like of int, agent ids ``1..n``
    pinned : the reference agent's id

    Returns
    -------
    The bound [1/m²] (inf when no edge moves a follower).
    """
    x = as_positions(positions)
    d = x.shape[1]
    r = sparse_rigidity_matrix(x, edges)
    keep = np.ones(r.shape[1], dtype=bool)
    keep[(pinned - 1) * d : pinned * d] = False
    followers = (r[:, keep].T @ r[:, keep]).tocsr()
    if followers.nnz == 0:
        return float("inf")
    if followers.shape[0] <= SVD_MAX_COLUMNS:
        top = float(np.linalg.eigvalsh(followers.toarray())[-1])
    else:  # Lanczos from a fixed start vector: the same answer every load
        start = np.ones(followers.shape[0])
        top = float(eigsh(followers, k=1, which="LA", v0=start, return_eigenvectors=False)[0])
    return 1.0 / top


def batched_ranks(blocks: FloatArray) -> IntArray:
    """:func:`rigidity_rank`'s count of each matrix of a stack ``(B, r, c)``."""
    s = np.linalg.svd(blocks, compute_uv=False)
    top = s[:, :1]
    ranks: IntArray = np.count_nonzero((s > RANK_RTOL * top) & (top > 0), axis=1)
    return ranks
