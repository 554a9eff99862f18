"""The leader's epoch (MODEL.md §4–§5) for a batch of independent members at once.

Used by ``testbed.sim.batch``; see its docstring for why a component-label sweep gives Kruskal's
forest and a dense grounded-Laplacian solve gives the BLUE of ``leader.blue``.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from formation.scenario import Scenario

Array = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]
Ints = npt.NDArray[np.int64]


def kruskal_order(scenario: Scenario) -> Ints:
    """Edge indices in Kruskal's order ``(w, min(i, j), max(i, j), index)`` (``leader.mst``)."""
    e, w = scenario.edge_array, scenario.weights
    order: Ints = np.lexsort((np.arange(len(e)), e[:, 1], e[:, 0], w)).astype(np.int64)
    return order


def batch_forest(n: int, edges: Ints, order: Ints, healthy: Mask) -> tuple[Mask, Ints]:
    """Minimum spanning forests of ``B`` healthy edge sets at once (MODEL.md §4).

    Parameters
    ----------
    n : agents; edges : (m, 2) agent ids; order : (m,) Kruskal's edge order
    healthy : (B, m) the edges each member may use

    Returns
    -------
    tree : (B, m) the forest's edges; labels : (B, n) a component label per agent
    """
    size = healthy.shape[0]
    labels = np.broadcast_to(np.arange(n, dtype=np.int64), (size, n)).copy()
    tree = np.zeros_like(healthy)
    for e in order.tolist():
        u, v = int(edges[e, 0]) - 1, int(edges[e, 1]) - 1
        lu, lv = labels[:, u], labels[:, v]
        keep = healthy[:, e] & (lu != lv)
        if not keep.any():
            continue
        tree[:, e] = keep
        move = keep[:, None] & (labels == lv[:, None])
        labels = np.where(move, lu[:, None], labels)
    return tree, labels


def batch_blue(
    n: int,
    edges: Ints,
    counts: Ints,
    fused: Array,
    observable: Mask,
    ref: int,
    x_ref: Array,
    cov: Array,
    covariances: bool,
) -> tuple[Array, Array | None]:
    """BLUE of ``B`` members at once for one noise covariance ``P`` on every edge (MODEL.md §5).

    Parameters
    ----------
    edges : (m, 2) agent ids ``(lo, hi)``; counts : (B, m) measurements used per edge (0, 1, 2)
    fused : (B, m, d) mean measured ``x_lo − x_hi`` of each used edge [m]
    observable : (B, n) agents joined to the reference by used edges
    ref : the reference agent; x_ref : (d,) its position [m]; cov : (d, d) ``P`` [m²]

    Returns
    -------
    positions : (B, n, d) [m], NaN where unobservable; covariances : (B, n, d, d) or None
    """
    size = counts.shape[0]
    d = fused.shape[2]
    lo, hi = edges[:, 0] - 1, edges[:, 1] - 1
    c = counts.astype(np.float64)
    # bincount, not matmul: a threaded BLAS call on these small arrays only spins (measured)
    base_nn = (np.arange(size, dtype=np.int64) * n * n)[:, None]
    cells = np.concatenate([lo * n + lo, hi * n + hi, lo * n + hi, hi * n + lo])[None, :]
    lap = np.bincount(
        (base_nn + cells).ravel(), np.concatenate([c, c, -c, -c], axis=1).ravel(), size * n * n
    ).reshape(size, n, n)  # Σ_e c_e h_e h_eᵀ, h_e = +1 at lo, −1 at hi
    base_n = (np.arange(size, dtype=np.int64) * n)[:, None]
    at = np.concatenate([base_n + lo[None, :], base_n + hi[None, :]], axis=1).ravel()
    weighted = c[:, :, None] * fused
    rhs = np.stack(
        [
            np.bincount(
                at,
                np.concatenate([weighted[:, :, a], -weighted[:, :, a]], axis=1).ravel(),
                size * n,
            )
            for a in range(d)
        ],
        axis=1,
    ).reshape(size, n, d)  # Σ_e c_e h_e ȳ_eᵀ
    keep = np.arange(n) != ref - 1
    grounded = lap[:, keep][:, :, keep]
    # Agents off the reference's component have no equations: an identity row keeps the
    # system regular and their rows are discarded.
    off = ~observable[:, keep]
    idx = np.arange(n - 1)
    grounded[:, idx, idx] += off
    positions = np.full((size, n, d), np.nan)
    positions[:, ref - 1] = x_ref
    blocks = None
    if covariances:
        blocks = np.full((size, n, d, d), np.nan)
        blocks[:, ref - 1] = 0.0
    if n == 1:
        return positions, blocks
    solved = np.linalg.solve(grounded, rhs[:, keep])
    rel = np.where(off[:, :, None], np.nan, solved)
    positions[:, keep] = x_ref + rel
    if blocks is not None:
        diag = np.linalg.inv(grounded)[:, idx, idx]
        diag = np.where(off, np.nan, diag)
        blocks[:, keep] = diag[:, :, None, None] * cov
    return positions, blocks


__all__ = ["batch_blue", "batch_forest", "kruskal_order"]
