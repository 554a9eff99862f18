"""Kruskal's minimum spanning forest over the healthy edges of an epoch (docs/model.md §4).

The leader keeps the forest's edges (the ``tree`` edge set of the estimator)
and its components (agents outside the reference's component are unobservable
this epoch). Pure: arrays in, arrays out.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from formation.graph import (
    GraphInputError,
    ShapeError,
    as_edge_array,
    as_edge_mask,
    check_agent_count,
)
from formation.graph import component_labels as components

__all__ = ["components", "minimum_spanning_forest"]

IntArray = npt.NDArray[np.int64]


def minimum_spanning_forest(
    n: int, edges: npt.ArrayLike, weights: npt.ArrayLike, healthy: npt.ArrayLike
) -> list[int]:
    """Minimum spanning forest of the healthy edges by Kruskal's algorithm (docs/model.md §4).

    Edges are taken in increasing ``(weight, min(i, j), max(i, j), index)``, a
    strict total order, so the forest is unique and does not depend on how the
    edges are listed (up to the index of parallel edges). An edge is kept when
    its endpoints are in different trees of a union-find with path compression
    and union by rank. The sort is vectorised; the union-find runs over chunks
    of the sorted edges, and between chunks every node is pointed at its root at
    once and the edges already inside one tree are dropped in bulk (Kruskal
    would reject them one by one), so the loop sees few more edges than it keeps.

    Parameters
    ----------
    n : int
        Number of agents; ids ``1..n``.
    edges : (m, 2) array_like of int
        Undirected edges as agent-id pairs.
    weights : (m,) array_like of float
        Edge weights (finite; any sign).
    healthy : (m,) array_like of bool
        Which edges may be used this epoch.

    Returns
    -------
    list of int
        Indices into ``edges`` of the forest's edges, in the order Kruskal
        accepted them. A forest of ``c`` components has ``n − c`` edges.

    Raises
    ------
    GraphInputError
        On wrong shapes, agent ids outside ``1..n``, self-loops or non-finite weights.
    """
    count = check_agent_count(n)
    e = as_edge_array(count, edges)
    m = e.shape[0]
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != (m,):
        raise ShapeError("weights", w.shape, f"({m},)")
    if not np.isfinite(w).all():
        k = int(np.flatnonzero(~np.isfinite(w))[0])
        raise GraphInputError(f"weights[{k}] = {w[k]}", "a finite weight")
    cand = np.flatnonzero(as_edge_mask(healthy, m, "healthy"))
    if cand.size == 0 or count == 1:
        return []
    lo = np.minimum(e[cand, 0], e[cand, 1]) - 1
    hi = np.maximum(e[cand, 0], e[cand, 1]) - 1
    order = _kruskal_order(w[cand], lo, hi)
    chosen = _union_find_scan(count, lo[order], hi[order])
    result: list[int] = cand[order[chosen]].tolist()
    return result


def _kruskal_order(w: npt.NDArray[np.float64], lo: IntArray, hi: IntArray) -> IntArray:
    """Positions sorting the edges by ``(w, lo, hi, position)``; ``lo``/``hi`` are 0-based."""
    order: IntArray = np.argsort(w)
    ws = w[order]
    if np.any(ws[1:] == ws[:-1]):  # ties: the plain sort is not deterministic, break them
        order = np.lexsort((np.arange(w.size), hi, lo, w))
    return order


def _union_find_scan(n: int, u: IntArray, v: IntArray) -> IntArray:
    """Kruskal's scan of sorted edges ``(u[k], v[k])`` (0-based nodes): positions of kept edges."""
    parent = list(range(n))
    rank = [0] * n
    kept: list[int] = []
    need = n - 1
    pending = np.arange(u.size)
    chunk = n
    while pending.size and len(kept) < need:
        take, pending = pending[:chunk], pending[chunk:]
        for k, a, b in zip(take.tolist(), u[take].tolist(), v[take].tolist(), strict=True):
            ra = a
            while parent[ra] != ra:
                ra = parent[ra]
            while parent[a] != ra:  # path compression
                parent[a], a = ra, parent[a]
            rb = b
            while parent[rb] != rb:
                rb = parent[rb]
            while parent[b] != rb:
                parent[b], b = rb, parent[b]
            if ra == rb:
                continue
            if rank[ra] < rank[rb]:  # union by rank
                parent[ra] = rb
            elif rank[ra] > rank[rb]:
                parent[rb] = ra
            else:
                parent[rb] = ra
                rank[ra] += 1
            kept.append(k)
            if len(kept) == need:
                break
        if pending.size and len(kept) < need:
            roots = _roots(np.asarray(parent, dtype=np.int64))
            parent = roots.tolist()  # full compression keeps the union-find valid
            pending = pending[roots[u[pending]] != roots[v[pending]]]
            chunk *= 2
    return np.asarray(kept, dtype=np.int64)


def _roots(parent: IntArray) -> IntArray:
    """Root of every node of a union-find forest, by pointer jumping."""
    while True:
        grand = parent[parent]
        if np.array_equal(grand, parent):
            return parent
        parent = grand
