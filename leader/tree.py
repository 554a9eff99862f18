"""The BLUE on a tree (docs/model.md §5): fusing repeated measurements, then path sums from the root.

On a tree ``H_b`` is square and invertible, so ``x̂_v − x_r`` is the sum of the
signed measurements on the path from the reference ``r`` to ``v``, and
``Cov(x̂_v)`` the sum of the ``P_e`` on it (independent noises add). Both are
computed for every node at once by pointer jumping over the BFS tree,
``O(n log depth)``. Several trees (the members of a batch, one root each) are
solved in one pass: each node's sums follow only its own path, so a tree gets
the same floats alone as beside others. ``leader.estimation`` chooses this solver.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.sparse import coo_array, csr_array
from scipy.sparse.csgraph import breadth_first_order

__all__ = ["adjacency", "fuse_parallel", "tree_solve"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


def adjacency(n: int, e: IntArray) -> csr_array:
    """The ``(n, n)`` adjacency pattern of the links ``e`` (``(k, 2)``, 0-based nodes)."""
    ones = np.ones(e.shape[0], dtype=np.int8)
    return csr_array(coo_array((ones, (e[:, 0], e[:, 1])), shape=(n, n)))


def fuse_parallel(
    n: int, e: IntArray, z: FloatArray, p: FloatArray
) -> tuple[IntArray, FloatArray, FloatArray]:
    """Merge measurements of the same pair (e.g. both directions of a link) into one.

    Two independent measurements of ``x_i − x_j`` are one with information
    ``Σ P_k⁻¹`` and value ``(Σ P_k⁻¹)⁻¹ Σ P_k⁻¹ z_k``; the BLUE is unchanged and a
    tree measured in both directions is still solved as a tree.

    Parameters
    ----------
    n : int
        Number of nodes (0-based ids below ``n``).
    e : (k, 2) int array
        Measured pairs ``(i, j)``, 0-based.
    z : (k, d) float array [m]
        ``z[q]`` measures ``x_i − x_j``.
    p : (k, d, d) float array [m²]
        Noise covariances.

    Returns
    -------
    e, z, p
        One row per distinct pair, where it first appears. A pair measured once
        is passed on as it came (same orientation, same floats); a fused one is
        oriented ``(min, max)``. So every pair's row depends only on its own
        measurements, whatever else is in the arrays (a batch's other members).
    """
    pairs = _pairs(n, e)
    if pairs is None:  # no pair measured twice
        return e, z, p
    rows, group, size, multi = pairs.rows, pairs.group, pairs.size, pairs.multi
    oriented = np.where(pairs.low_first[:, None], z[rows], -z[rows])  # x_lo − x_hi
    info = _inverses(p[rows])
    info_sum = _group_sums(group, info, size)
    weighted = _group_sums(group, np.einsum("eab,eb->ea", info, oriented), size)
    fused_p = _inverses(info_sum[multi])
    fused_p = 0.5 * (fused_p + fused_p.transpose(0, 2, 1))
    out_z, out_p = z[pairs.first], p[pairs.first]
    out_z[multi] = np.einsum("eab,eb->ea", fused_p, weighted[multi])
    out_p[multi] = fused_p
    return pairs.fused, out_z[pairs.order], out_p[pairs.order]


@dataclass(frozen=True, eq=False)
class _Pairs:
    """Which measurements :func:`fuse_parallel` merges: what depends on the pairs only.

    rows : the measurements of a pair measured more than once; group : (len(rows),) their
    pair; low_first : whether each is oriented ``(lo, hi)``; size : distinct pairs; multi :
    the pairs measured more than once; first : (size,) where each pair first appears;
    order : the pairs by first appearance; fused : the output's pairs (read-only)
    """

    rows: IntArray
    group: IntArray
    low_first: npt.NDArray[np.bool_]
    size: int
    multi: IntArray
    first: IntArray
    order: IntArray
    fused: IntArray


class _LastPairs:
    """The last measured pairs grouped, with their key (as :class:`_LastWalk`)."""

    slot: tuple[tuple[Any, ...], _Pairs | None] | None = None


def _pairs(n: int, e: IntArray) -> _Pairs | None:
    """The :class:`_Pairs` of ``e``, None when no pair is measured twice."""
    key = (n, e.shape, e.dtype.str, np.ascontiguousarray(e).tobytes())
    last = _LastPairs.slot
    if last is not None and last[0] == key:
        return last[1]
    lo, hi = np.minimum(e[:, 0], e[:, 1]), np.maximum(e[:, 0], e[:, 1])
    pair = lo * n + hi
    keys, first, group, counts = pair_groups(pair)
    found = None
    if keys.size != pair.size:
        rows = np.flatnonzero(counts[group] > 1)
        multi = np.flatnonzero(counts > 1)
        fused = e[first]
        fused[multi] = np.stack([keys[multi] // n, keys[multi] % n], axis=1)
        order = np.argsort(first)
        fused = fused[order]
        fused.flags.writeable = False  # the output of every call with these pairs
        low_first = e[rows, 0] == lo[rows]
        found = _Pairs(rows, group[rows], low_first, keys.size, multi, first, order, fused)
    _LastPairs.slot = (key, found)
    return found


def pair_groups(pair: IntArray) -> tuple[IntArray, IntArray, IntArray, IntArray]:
    """``np.unique(pair, return_index=True, return_inverse=True, return_counts=True)`` of
    non-negative keys, the same four arrays.

    Each key made distinct by its row (``pair · k + row``) is one sort without the stable
    sort's merge passes; where that could overflow, ``np.unique`` itself.
    """
    k = pair.size
    if k == 0 or int(pair.max()) >= np.iinfo(np.int64).max // (2 * k):
        out: tuple[IntArray, IntArray, IntArray, IntArray] = np.unique(
            pair, return_index=True, return_inverse=True, return_counts=True
        )
        return out
    perm = np.argsort(pair * k + np.arange(k))  # distinct keys: any sort is the stable one
    aux = pair[perm]
    new = np.empty(k, dtype=bool)
    new[0] = True
    np.not_equal(aux[1:], aux[:-1], out=new[1:])
    group = np.empty(k, dtype=np.int64)
    group[perm] = np.cumsum(new) - 1
    starts = np.flatnonzero(new)
    return aux[new], perm[new], group, np.diff(np.append(starts, k))


def _group_sums(group: IntArray, values: FloatArray, size: int) -> FloatArray:
    """Per group ``g < size`` the sum of the rows ``values[group == g]``, added in row order.

    ``np.bincount`` adds each row into its group in order from 0.0, as ``np.add.at``
    does (the same floats), one column at a time instead of one row at a time.
    """
    flat = values.reshape(values.shape[0], -1)
    out = np.empty((size, flat.shape[1]))
    for c in range(flat.shape[1]):
        out[:, c] = np.bincount(group, weights=flat[:, c], minlength=size)
    return out.reshape(size, *values.shape[1:])


def _inverses(m: FloatArray) -> FloatArray:
    """``np.linalg.inv`` of each matrix of a stack ``(k, d, d)``; one inversion if all are equal.

    A team's covariances are mostly one matrix, as are their fused sums: the same floats
    as inverting every copy, without thousands of small LAPACK calls.
    """
    if m.shape[0] > 1 and (m == m[0]).all():
        out: FloatArray = np.broadcast_to(np.linalg.inv(m[:1]), m.shape).copy()
    else:
        out = np.linalg.inv(m).astype(np.float64, copy=False)
    return out


@dataclass(frozen=True, eq=False)
class _Walk:
    """The path sums' structure on trees: what depends on the links and roots only.

    nodes : (N,) the non-root nodes in BFS order; edge : (N,) the link joining each to its
    parent; sign : (N,) +1 where the node is the link's ``i``; jumps : the ancestor arrays
    of pointer jumping, one per round (``rel[v] += rel[anc[v]]``)
    """

    nodes: IntArray
    edge: IntArray
    sign: FloatArray
    jumps: list[IntArray]


class _LastWalk:
    """The last trees walked, with their key: a leader whose used links repeat epoch after
    epoch walks them once. Only the structure is kept, so the sums are the same floats
    either way. One slot, replaced whole (threads read it once)."""

    slot: tuple[tuple[Any, ...], _Walk] | None = None


def _walk(n: int, e: IntArray, roots: IntArray, graph: csr_array | None) -> _Walk:
    """The :class:`_Walk` of the trees ``e`` from ``roots`` (the last one again if the same)."""
    key = (n, e.shape, e.dtype.str, np.ascontiguousarray(e).tobytes(), roots.tobytes())
    last = _LastWalk.slot
    if last is not None and last[0] == key:
        return last[1]
    if roots.size == 1:
        source, skip = int(roots[0]), 1
        if graph is None:
            graph = adjacency(n, e)
    else:
        source, skip = n, 1 + roots.size  # one extra node joined to every root: one BFS
        pairs = np.concatenate([e, np.stack([np.full(roots.size, n), roots], axis=1)])
        graph = adjacency(n + 1, pairs)
    order, pred = breadth_first_order(graph, source, directed=False, return_predecessors=True)
    nodes: IntArray = order[skip:].astype(np.int64)  # the roots come first
    parents: IntArray = pred[nodes].astype(np.int64)
    # the tree link joining each node to its parent, by key lo·n + hi
    lo, hi = np.minimum(e[:, 0], e[:, 1]), np.maximum(e[:, 0], e[:, 1])
    keys = lo * n + hi
    sort = np.argsort(keys)
    want = np.minimum(nodes, parents) * n + np.maximum(nodes, parents)
    edge = sort[np.searchsorted(keys[sort], want)]  # the sorted copy: no indirect search
    # z_e = x_i − x_j, so x_node − x_parent = +z_e when the node is i, −z_e when it is j
    sign = np.where(e[edge, 0] == nodes, 1.0, -1.0)
    anc = np.arange(n)
    anc[nodes] = parents
    jumps = []
    # pointer jumping: rel[v] = x_v − x_anc[v]; doubling the jump each round (a root adds 0)
    while True:
        up = anc[anc]
        if np.array_equal(up, anc):
            break
        jumps.append(anc)
        anc = up
    walk = _Walk(nodes, edge, sign, jumps)
    _LastWalk.slot = (key, walk)
    return walk


def tree_solve(
    n: int,
    e: IntArray,
    z: FloatArray,
    p: FloatArray,
    roots: IntArray,
    x_r: FloatArray,
    positions: FloatArray,
    blocks: FloatArray | None,
    graph: csr_array | None = None,
) -> None:
    """Path sums from the roots over the trees ``e``, written into the outputs.

    Parameters
    ----------
    n : int
        Number of nodes (rows of the outputs).
    e : (k, 2) int array
        The trees' links, 0-based, one per pair (after :func:`fuse_parallel`).
    z : (k, d) float array [m]
        ``z[q] = x_i − x_j`` for ``e[q] = (i, j)``.
    p : (k, d, d) float array [m²]
        Their noise covariances.
    roots : (R,) int array
        One root per tree (the reference of each member), at ``x_r``.
    x_r : (d,) float array [m]
        The roots' known position.
    positions : (n, d) float array [m]
        Written at every non-root node of the trees.
    blocks : (n, d, d) float array [m²] or None
        Covariance blocks, written likewise when given.
    graph : (n, n) csr_array, optional
        With one root: an adjacency whose root's component is its tree (the caller's,
        so none is built here).
    """
    walk = _walk(n, e, roots, graph)
    nodes, edge = walk.nodes, walk.edge
    rel = np.zeros((n, z.shape[1]))
    rel[nodes] = walk.sign[:, None] * z[edge]
    acc = None
    if blocks is not None:
        acc = np.zeros((n, *p.shape[1:]))
        acc[nodes] = p[edge]
    for anc in walk.jumps:
        rel += rel[anc]  # the gather is a copy: every node adds its ancestor's old sum
        if acc is not None:
            acc += acc[anc]
    positions[nodes] = x_r + rel[nodes]
    if blocks is not None and acc is not None:
        blocks[nodes] = acc[nodes]
