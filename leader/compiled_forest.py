"""Kruskal's scan of a batch, compiled: the edges in their fixed order through a union-find,
no sort per epoch (docs/model.md §4).

The forest and the component labels are :func:`leader.mst._sparse_scan`'s, equal array for
array (``tests/unit/leader/test_mst.py``): with every edge's place distinct the minimum
forest is unique, and the labels number the components by their smallest node, as SciPy's
``connected_components`` does.
"""

from __future__ import annotations

import numpy as np

from formation.compiled import jit
from formation.graph import BoolArray, IntArray


@jit
def _root(parent: IntArray, v: int) -> int:
    while parent[v] != v:
        parent[v] = parent[parent[v]]  # path halving
        v = parent[v]
    return v


@jit
def kruskal_scan(
    n: int, lo: IntArray, hi: IntArray, order: IntArray, healthy: BoolArray
) -> tuple[BoolArray, IntArray]:
    """Each member's forest: ``tree`` (B, m), and ``labels`` (B n,) of one graph of ``B n``
    nodes, member ``b``'s agent ``i`` its node ``b n + i``, numbered ``0, 1, …`` by each
    component's smallest node."""
    size, m = healthy.shape
    tree = np.zeros((size, m), dtype=np.bool_)
    parent = np.arange(size * n)
    for b in range(size):
        base = b * n
        for k in range(m):
            e = order[k]
            if not healthy[b, e]:
                continue
            u = _root(parent, base + lo[e])
            v = _root(parent, base + hi[e])
            if u == v:
                continue
            tree[b, e] = True
            if u < v:
                parent[v] = u
            else:
                parent[u] = v
    label_of_root = np.full(size * n, -1, dtype=np.int64)
    labels = np.empty(size * n, dtype=np.int64)
    count = 0
    for v in range(size * n):
        r = _root(parent, v)
        if label_of_root[r] < 0:
            label_of_root[r] = count
            count += 1
        labels[v] = label_of_root[r]
    return tree, labels
