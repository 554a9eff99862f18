"""Kruskal's minimum spanning forest over the healthy edges of an epoch (docs/model.md §4).

The leader keeps the forest's edges (the ``tree`` edge set of the estimator)
and its components (agents outside the reference's component are unobservable
this epoch). Pure: arrays in, arrays out.

The leader runs :meth:`KruskalGraph.forests`: one epoch of ``B`` independent runs of
one graph (a batch of seeds; one run is a batch of one), in the order of
:func:`minimum_spanning_forest`, the one-run form the tests hold the batch to.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components, minimum_spanning_tree

from formation.errors import GraphInputError, ShapeError
from formation.graph import as_edge_array, as_edge_mask, check_agent_count
from formation.graph import component_labels as components

__all__ = ["KruskalGraph", "components", "minimum_spanning_forest"]

IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

LABEL_SWEEP_RATIO = 12
"""A batch scans by labels when ``m × 12 < B n``: many members of a small graph, the
sweep's batches (``bench/bench_sweep.py``); others by the compiled scan."""


def minimum_spanning_forest(
    n: int, edges: npt.ArrayLike, weights: npt.ArrayLike, healthy: npt.ArrayLike
) -> list[int]:
    """Minimum spanning forest of the healthy edges by Kruskal's algorithm (docs/model.md §4).

    The one-run form: the leader calls :meth:`KruskalGraph.forests` (a batch); this is the
    reference the tests hold that to (and check against SciPy and a textbook Kruskal), and
    the baseline ``bench/bench_leader.py`` times. Edges are taken in increasing ``(weight, min(i, j), max(i, j), index)``, a
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
    count, e, w = _check_graph(n, edges, weights)
    cand = np.flatnonzero(as_edge_mask(healthy, e.shape[0], "healthy"))
    if cand.size == 0 or count == 1:
        return []
    lo = np.minimum(e[cand, 0], e[cand, 1]) - 1
    hi = np.maximum(e[cand, 0], e[cand, 1]) - 1
    order = _kruskal_order(w[cand], lo, hi)
    chosen, _ = _union_find_scan(count, lo[order], hi[order])
    result: list[int] = cand[order[chosen]].tolist()
    return result


@dataclass(frozen=True, eq=False)
class KruskalGraph:
    """A graph checked once, its edges in Kruskal's order, for the forests of many epochs.

    lo, hi : (m,) 0-based ends of each edge, ``lo < hi``; order : (m,) Kruskal's edge order
    """

    n: int
    lo: IntArray
    hi: IntArray
    order: IntArray

    @classmethod
    def of(cls, n: int, edges: npt.ArrayLike, weights: npt.ArrayLike) -> KruskalGraph:
        """Check ``n``, the ``(m, 2)`` edges and the ``(m,)`` weights; sort once."""
        count, e, w = _check_graph(n, edges, weights)
        lo = np.minimum(e[:, 0], e[:, 1]) - 1
        hi = np.maximum(e[:, 0], e[:, 1]) - 1
        return cls(count, lo, hi, _kruskal_order(w, lo, hi))

    def forests(self, healthy: BoolArray) -> tuple[BoolArray, IntArray]:
        """Kruskal's forest of each of ``B`` healthy edge sets of this graph (docs/model.md §4).

        Member ``b``'s agent ``i`` is agent ``b·n + i`` of one graph of ``B·n`` agents; its
        edges are scanned in the members' common order (that of
        :func:`minimum_spanning_forest`, member after member for each edge). Kruskal's forest
        of a disjoint union is the union of the members' forests, so one union-find scan
        gives each member exactly its own forest.

        A batch of ``UNION_FIND_FROM`` nodes or more is scanned by a compiled union-find,
        the edges in the order (:mod:`leader.compiled_forest`). A smaller one takes SciPy's
        compiled Kruskal (:func:`scipy.sparse.csgraph.minimum_spanning_tree`) with each edge
        weighted by its place in the order: distinct weights have one minimum forest, the
        one the scan in that order keeps; or, many members of a small graph
        (``m × LABEL_SWEEP_RATIO < B n``), it is scanned edge by edge across the members,
        with labels for the components (:func:`_label_sweep`); or, at most
        ``SCAN_IN_PYTHON_UPTO`` edges in all (``B m``), by the union-find of
        :func:`minimum_spanning_forest` in Python (:func:`_python_scan`). The same edges are
        kept (``tests/unit/leader/test_mst.py`` holds the four paths to
        :func:`minimum_spanning_forest`).

        Parameters
        ----------
        healthy : (B, m) bool array
            The edges each member may use.

        Returns
        -------
        tree : (B, m) bool array
            The forest's edges of each member.
        labels : (B, n) int array
            A component label per agent (distinct across members): agents share a
            label when the member's forest joins them.
        """
        size, m, count = healthy.shape[0], self.lo.size, self.n
        if healthy.shape != (size, m) or healthy.dtype != np.bool_:
            raise ShapeError("healthy", healthy.shape, f"(B, {m}) bool")
        if size * count >= UNION_FIND_FROM:
            return _union_find(count, self.lo, self.hi, self.order, healthy)
        if m * LABEL_SWEEP_RATIO < size * count:
            return _label_sweep(count, self.lo, self.hi, self.order, healthy)
        if size * m <= SCAN_IN_PYTHON_UPTO:
            return _python_scan(count, self.lo, self.hi, self.order, healthy)
        return _sparse_scan(count, self.lo, self.hi, self.order, healthy)


UNION_FIND_FROM = 2048
"""A batch of this many nodes (``B n``) or more is scanned by the compiled union-find: the
edges in their fixed order, no sort per epoch. Smaller ones take SciPy or the label sweep
rather than load numba (about a second) in a small leader's process."""


SCAN_IN_PYTHON_UPTO = 1024
"""A batch of at most this many edges (``B m``, healthy or not) is scanned by
:func:`_union_find_scan` in Python: SciPy's sparse matrices cost more to build than a small
team's scan: a batch of 16 runs of the chapter's 5 agents took 0.48 ms an epoch by SciPy,
0.05 ms by this scan, which stays ahead up to about a thousand edges."""


def _python_scan(
    n: int, lo: IntArray, hi: IntArray, order: IntArray, healthy: BoolArray
) -> tuple[BoolArray, IntArray]:
    """Each member's Kruskal forest by one :func:`_union_find_scan` of the members' disjoint
    union, in the order of :meth:`KruskalGraph.forests`; labels as :func:`_sparse_scan`'s
    (each component numbered in the order of its smallest node)."""
    size = healthy.shape[0]
    at, member = np.nonzero(healthy[:, order].T)  # for each edge in order, member after member
    edge = order[at]
    kept, parent = _union_find_scan(size * n, member * n + lo[edge], member * n + hi[edge])
    tree = np.zeros(healthy.shape, dtype=bool)
    tree[member[kept], edge[kept]] = True
    roots = _roots(np.asarray(parent, dtype=np.int64))
    _, first, component = np.unique(roots, return_index=True, return_inverse=True)
    number = np.empty(first.size, dtype=np.int64)
    number[np.argsort(first)] = np.arange(first.size)
    return tree, number[component].reshape(size, n)


def _union_find(
    n: int, lo: IntArray, hi: IntArray, order: IntArray, healthy: BoolArray
) -> tuple[BoolArray, IntArray]:
    """Each member's Kruskal forest by the compiled union-find (:mod:`leader.compiled_forest`)."""
    from leader.compiled_forest import kruskal_scan

    tree, labels = kruskal_scan(n, lo, hi, order, np.ascontiguousarray(healthy))
    return tree, labels.reshape(healthy.shape[0], n)


def _sparse_scan(
    n: int, lo: IntArray, hi: IntArray, order: IntArray, healthy: BoolArray
) -> tuple[BoolArray, IntArray]:
    """Kruskal's forest of each member by SciPy, each edge weighted ``1 + its place in order``.

    Members are disjoint blocks of one graph of ``B n`` nodes. An edge listed twice
    would be summed into one entry, so the later of two copies (never kept: its ends are
    joined by then) is dropped first.
    """
    size, m = healthy.shape
    place = np.empty(m, dtype=np.int64)
    place[order] = np.arange(m)
    by_pair = np.argsort(lo * n + hi, kind="stable")
    pairs = (lo * n + hi)[by_pair]
    if np.all(pairs[1:] != pairs[:-1]):  # no edge listed twice: sorted by pair, member-major
        member, at = np.nonzero(healthy[:, by_pair])
        edge = by_pair[at]
    else:
        member, edge = np.nonzero(healthy)
        pair = (member * n + lo[edge]) * n + hi[edge]
        by = np.lexsort((place[edge], pair))
        first = by[np.r_[True, pair[by][1:] != pair[by][:-1]]] if by.size else by
        member, edge = member[first], edge[first]
    base = member * n
    graph = csr_matrix(
        ((place[edge] + 1).astype(np.float64), (base + lo[edge], base + hi[edge])),
        shape=(size * n, size * n),
    )
    forest = minimum_spanning_tree(graph).tocoo()
    kept = order[forest.data.astype(np.int64) - 1]
    tree = np.zeros(healthy.shape, dtype=bool)
    tree[forest.row // n, kept] = True
    labels = connected_components(forest, directed=False)[1].astype(np.int64)
    return tree, labels.reshape(size, n)


def _label_sweep(
    n: int, lo: IntArray, hi: IntArray, order: IntArray, healthy: BoolArray
) -> tuple[BoolArray, IntArray]:
    """Kruskal's scan for many members of a small graph: one step per edge, across members.

    Each member's components are kept as labels; an edge is kept where its ends carry
    different labels, and one label then takes the other's agents. ``O(m · B n)`` work in
    ``m`` vectorised steps, where the union-find takes ``B n`` Python steps.
    """
    size = healthy.shape[0]
    labels = np.broadcast_to(np.arange(n, dtype=np.int64), (size, n)).copy()
    tree = np.zeros_like(healthy)
    for e in order.tolist():
        lu, lv = labels[:, lo[e]], labels[:, hi[e]]
        keep = healthy[:, e] & (lu != lv)
        if not keep.any():
            continue
        tree[:, e] = keep
        move = keep[:, None] & (labels == lv[:, None])
        labels = np.where(move, lu[:, None], labels)
    labels += (np.arange(size, dtype=np.int64) * n)[:, None]  # distinct across members
    return tree, labels


def _check_graph(
    n: int, edges: npt.ArrayLike, weights: npt.ArrayLike
) -> tuple[int, IntArray, npt.NDArray[np.float64]]:
    """The agent count, the ``(m, 2)`` edges and the finite ``(m,)`` weights, checked."""
    count = check_agent_count(n)
    e = as_edge_array(count, edges)
    m = e.shape[0]
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != (m,):
        raise ShapeError("weights", w.shape, f"({m},)")
    if not np.isfinite(w).all():
        k = int(np.flatnonzero(~np.isfinite(w))[0])
        raise GraphInputError(f"weights[{k}] = {w[k]}", "a finite weight")
    return count, e, w


def _kruskal_order(w: npt.NDArray[np.float64], lo: IntArray, hi: IntArray) -> IntArray:
    """Positions sorting the edges by ``(w, lo, hi, position)``; ``lo``/``hi`` are 0-based."""
    order: IntArray = np.argsort(w)
    ws = w[order]
    if np.any(ws[1:] == ws[:-1]):  # ties: the plain sort is not deterministic, break them
        order = np.lexsort((np.arange(w.size), hi, lo, w))
    return order


def _union_find_scan(n: int, u: IntArray, v: IntArray) -> tuple[IntArray, list[int]]:
    """Kruskal's scan of sorted edges ``(u[k], v[k])`` (0-based nodes).

    Returns the positions of the kept edges and the union-find's parent array.
    """
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
    return np.asarray(kept, dtype=np.int64), parent


def _roots(parent: IntArray) -> IntArray:
    """Root of every node of a union-find forest, by pointer jumping."""
    while True:
        grand = parent[parent]
        if np.array_equal(grand, parent):
            return parent
        parent = grand
