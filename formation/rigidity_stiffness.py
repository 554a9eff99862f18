"""Rigidity of large frameworks by the pinned stiffness ``RᵀR + CᵀC`` (docs/model.md §2).

Pinning the rigid motions (``C``) leaves a matrix that is definite iff the framework is
rigid; a sparse LU and a few steps of block inverse iteration find its weakest motions.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.sparse import csr_matrix
from scipy.sparse.linalg import splu

from formation.graph import FloatArray, as_positions
from formation.rigidity import RANK_RTOL, sparse_rigidity_matrix

INVERSE_STEPS = 4
"""Steps of block inverse iteration that find the pinned stiffness's weakest motions."""

INVERSE_BLOCK = 3
"""Vectors of that block: the weakest motion is found in it even when the pinning mixes
the order of a few nearly as weak ones."""


def _pinning(x: FloatArray) -> FloatArray | None:
    """Rows ``C`` (D, n·d) that fix the ``D = d(d+1)/2`` rigid motions, or None if ``x`` is flat.

    Agent ``a`` (the first) is held; ``b``, the farthest from it, may only slide along
    ``b − a``; in 3-D, ``c``, the farthest from that line, only within the plane ``a b c``.
    """
    n, d = x.shape
    a = 0
    rel = x - x[a]
    b = int(np.argmax(np.linalg.norm(rel, axis=1)))
    span = [rel[b] / np.linalg.norm(rel[b])] if np.linalg.norm(rel[b]) > 0 else []
    if not span:
        return None
    rows: list[tuple[int, FloatArray]] = [(a, np.eye(d)[k]) for k in range(d)]
    basis = np.linalg.svd(np.array(span).reshape(1, d))[2]
    rows += [(b, v) for v in basis[1:]]
    if d == 3:
        off = rel - np.outer(rel @ span[0], span[0])
        c = int(np.argmax(np.linalg.norm(off, axis=1)))
        if np.linalg.norm(off[c]) <= RANK_RTOL * np.linalg.norm(rel[b]):
            return None
        rows.append((c, np.cross(span[0], off[c] / np.linalg.norm(off[c]))))
    elif d != 2:
        return None  # the pinning is written for the plane and space only
    if d == 2 and np.linalg.norm(rel - np.outer(rel @ span[0], span[0]), axis=1).max() <= (
        RANK_RTOL * np.linalg.norm(rel[b])
    ):
        return None
    out = np.zeros((len(rows), n * d))
    for r, (agent, v) in enumerate(rows):
        out[r, agent * d : (agent + 1) * d] = v
    return out


def pinned_stiffness_definite(positions: npt.ArrayLike, edges: npt.ArrayLike) -> bool:
    """Whether the framework is rigid, by the pinned stiffness ``RᵀR + CᵀC`` (§2).

    ``C`` (:func:`_pinning`) removes exactly the rigid motions when the agents span the
    space, so the stiffness is definite iff rigid. A sparse LU (SuperLU) of it and a few
    steps of block inverse iteration give the motions it resists least; the least singular
    value of ``R`` on them, less their rigid part, bounds ``σ_r``, the least nonzero
    singular value of ``R`` the SVD would find, from above and reaches it. It must exceed
    ``RANK_RTOL · σ_max``, the SVD's own test. Agents on a line (in 3-D, a plane) are
    never rigid once there are more than ``d`` of them.
    """
    x = as_positions(positions)
    pins = _pinning(x)
    if pins is None:
        return False
    r = sparse_rigidity_matrix(x, edges)
    return _least_motion_resisted(r, csr_matrix(pins), rigid_motions(x))


def full_column_rank(r: csr_matrix) -> bool:
    """Whether a sparse ``r`` has full column rank at the SVD's tolerance (§2).

    As :func:`pinned_stiffness_definite` with nothing pinned: ``rᵀr`` must be definite,
    and the least singular value of ``r`` on the motions it resists least must exceed
    ``RANK_RTOL`` of its largest one. For the agents outside a rigid spanning cluster,
    whose edges into the cluster already pin them.
    """
    if r.shape[0] < r.shape[1]:
        return False
    if r.shape[1] == 0:
        return True
    return _least_motion_resisted(r, None, np.zeros((r.shape[1], 0)))


def _least_motion_resisted(r: csr_matrix, c: csr_matrix | None, motions: FloatArray) -> bool:
    """Whether ``σ_min(r)`` less ``motions`` exceeds ``RANK_RTOL · σ_max(r)``, by ``rᵀr + cᵀc``."""
    k = (r.T @ r if c is None else r.T @ r + c.T @ c).tocsc()
    try:
        lu = splu(  # symmetric ordering, diagonal pivots: a quarter of partial pivoting's fill
            k, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}
        )
    except RuntimeError:  # an exactly zero pivot: singular
        return False
    y = np.random.default_rng(0).standard_normal((k.shape[0], INVERSE_BLOCK))
    for _ in range(INVERSE_STEPS):
        y = lu.solve(np.linalg.qr(y)[0])
        if not np.isfinite(y).all():
            return False
    # Rayleigh–Ritz on R itself over the block less the rigid motions (QR: orthonormal even
    # where the block nearly holds one). Not on RᵀR: its eigenvalues are the squares, and the
    # SVD's tolerance squared (1e-18 of the largest) is below their rounding.
    weak = np.linalg.qr(np.hstack([motions, y]))[0][:, motions.shape[1] :]
    weakest = np.linalg.svd(r @ weak, compute_uv=False)[-1]
    return bool(weakest > RANK_RTOL * _largest_singular_value(r))


def rigid_motions(x: FloatArray) -> FloatArray:
    """The ``d(d+1)/2`` rigid motions ``(n·d, D)`` of agents at ``x``, independent if they span.

    The ``d`` translations and, for each plane ``(a, b)`` of coordinates, the rotation
    ``v_a = −x_b, v_b = x_a`` about the centroid.
    """
    n, d = x.shape
    centred = x - x.mean(axis=0)
    motions = [np.tile(np.eye(d)[k], n) for k in range(d)]
    for a in range(d):
        for b in range(a + 1, d):
            v = np.zeros((n, d))
            v[:, a], v[:, b] = -centred[:, b], centred[:, a]
            motions.append(v.ravel())
    return np.array(motions).T


POWER_STEPS = 30
"""Steps of power iteration for ``σ_max``; it nears from below, within a few per cent."""


def _largest_singular_value(r: csr_matrix) -> float:
    """``σ_max`` of a sparse matrix by power iteration on ``rᵀr`` (a fixed start)."""
    v = np.random.default_rng(0).standard_normal(r.shape[1])
    for _ in range(POWER_STEPS):
        v = r.T @ (r @ v)
        v /= np.linalg.norm(v)
    return float(np.linalg.norm(r @ v))
