"""The agents a grown rigid cluster leaves out, and the rigid clusters among them (§2).

Vertex addition on an epoch's kept edges grows a rigid cluster over most agents; it is held
still. The agents outside it are free (``d`` columns each) or belong to further rigid
clusters (:data:`HELD`, :data:`FREE` and ``1, 2, …`` label them: their *bodies*), each of
which moves only rigidly: ``D = d(d+1)/2`` columns, an orthonormal basis of its rigid
motions. The motions that hold the first cluster still are the kernel of ``R_B``, the
rigidity matrix on those columns in the rows of the edges not inside one cluster, so
``rank R = expected(n, d) − columns(R_B) + rank R_B`` (docs/model.md §2, step 4). ``R_B``
is block diagonal over the components its rows join: small ones by dense SVDs, the others by
a count and a sparse stiffness. Without further clusters ``R_B`` is ``R_U``, the columns of
the agents outside the first cluster.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.sparse import csr_matrix

from formation.graph import FloatArray, IntArray, component_labels
from formation.rigidity import batched_ranks, expected_rigidity_rank
from formation.rigidity_stiffness import full_column_rank, rigid_motions

HELD = 0
"""The body label of the first grown cluster, held still."""
FREE = -1
"""The body label of an agent in no rigid cluster."""


class OutsideMatrix(NamedTuple):
    """``R_B`` as entries, with the components its rows join."""

    row: IntArray
    """Each entry's row: its edge's index among the edges not inside one cluster."""
    column: IntArray
    """Each entry's column in ``R_B``: its node's columns, node after node."""
    local: IntArray
    """Each entry's column within its component's block."""
    value: FloatArray
    component: IntArray
    """Each entry's component, ``0 … c − 1``."""
    columns: IntArray
    """(c,) columns of each component."""
    rows: int
    """Rows of ``R_B``."""


def outside_matrix(x: FloatArray, edges: IntArray, bodies: IntArray) -> OutsideMatrix:
    """``R_B`` of agents at ``x`` (n, d), ``edges`` (m, 2) ids ``1..n``, ``bodies`` (n,) labels.

    Its nodes are the free agents (``d`` columns each, node ``a``) and the further clusters
    (``D`` columns each, node ``n + label − 1``), in that order; an edge's row holds
    ``(x_i − x_j)ᵀ`` times agent ``i``'s velocity columns and ``−(x_i − x_j)ᵀ`` agent ``j``'s.
    """
    n, d = x.shape
    e0 = edges - 1
    bodies = bodies.astype(np.int64, copy=False)
    further = int(bodies.max(initial=HELD))
    free = bodies == FREE
    node = np.where(free, np.arange(n), n + bodies - 1)
    node[bodies == HELD] = -1
    width = np.zeros(n + further, dtype=np.int64)
    width[:n][free] = d
    width[n:] = d * (d + 1) // 2
    basis = np.zeros((n, d, d * (d + 1) // 2))  # a cluster agent's velocity per motion
    for label in range(1, further + 1):
        agents = np.flatnonzero(bodies == label)
        q = np.linalg.qr(rigid_motions(x[agents]))[0]
        basis[agents] = q.reshape(agents.shape[0], d, -1)
    ends = bodies[e0]
    inside = (ends[:, 0] != FREE) & (ends[:, 0] == ends[:, 1])
    pairs = node[e0[~inside]]  # (rows, 2)
    diff = x[e0[~inside, 0]] - x[e0[~inside, 1]]
    used = np.flatnonzero(width > 0)
    joined = (pairs >= 0).all(axis=1)
    labels = component_labels(n + further, pairs[joined] + 1)[used]
    component = np.unique(labels, return_inverse=True)[1]
    of_node = np.full(n + further, -1, dtype=np.int64)
    of_node[used] = component
    order = np.argsort(component, kind="stable")  # nodes by component, each in node order
    columns = np.bincount(component, weights=width[used]).astype(np.int64)
    within = np.cumsum(width[used][order]) - width[used][order]
    local = np.zeros(n + further, dtype=np.int64)
    local[used[order]] = within - (np.cumsum(columns) - columns)[component[order]]
    first = np.zeros(n + further, dtype=np.int64)
    first[used] = np.cumsum(width[used]) - width[used]
    motions = d * (d + 1) // 2
    kept = e0[~inside]
    parts = []
    for side, sign in ((0, 1.0), (1, -1.0)):
        has = np.flatnonzero(pairs[:, side] >= 0)
        at, agent, along = pairs[has, side], kept[has, side], sign * diff[has]
        values = np.zeros((has.shape[0], motions))
        cluster = at >= n
        values[~cluster, :d] = along[~cluster]
        values[cluster] = np.einsum("rd,rdk->rk", along[cluster], basis[agent[cluster]])
        slot = np.arange(motions)
        keep = slot[None, :] < width[at][:, None]
        per = keep.sum(axis=1)
        parts.append(
            (
                np.repeat(has, per),
                (first[at][:, None] + slot)[keep],
                (local[at][:, None] + slot)[keep],
                values[keep],
                np.repeat(of_node[at], per),
            )
        )
    row, column, local_column, value, comp = (np.concatenate(p) for p in zip(*parts, strict=True))
    return OutsideMatrix(row, column, local_column, value, comp, columns, int(pairs.shape[0]))


def outside_rank(x: FloatArray, edges: IntArray, bodies: IntArray, max_columns: int) -> int | None:
    """``rank R`` from the bodies: ``expected(n, d) − columns(R_B) + rank R_B`` (module doc).

    Each component of ``R_B`` by a dense SVD (one batched SVD per column count); None when
    one has more than ``max_columns`` columns.
    """
    n, d = x.shape
    r = outside_matrix(x, edges, bodies)
    if r.columns.size and r.columns.max() > max_columns:
        return None
    rank = 0
    for k in np.unique(r.columns):  # a dense stack per column count, one batched SVD each
        chosen = r.columns[r.component] == k
        if not chosen.any():
            continue  # components without a row: rank 0
        slot = np.cumsum(r.columns == k) - 1  # component → its index in the stack
        c = slot[r.component[chosen]]
        # rows numbered within their component
        key = c.astype(np.int64) * (r.rows + 1) + r.row[chosen]
        uniq, inverse = np.unique(key, return_inverse=True)
        owner = uniq // (r.rows + 1)
        local = np.arange(uniq.size) - np.searchsorted(owner, owner)
        stack = np.zeros((int((r.columns == k).sum()), int(local.max()) + 1, int(k)))
        stack[c, local[inverse], r.local[chosen]] = r.value[chosen]
        rank += int(batched_ranks(stack).sum())
    return int(expected_rigidity_rank(n, d) - int(r.columns.sum()) + rank)


def unbraced_outside(r: OutsideMatrix) -> bool:
    """Whether a component of ``R_B`` has fewer rows than columns: it cannot have full column
    rank, so the framework is flexible."""
    first = np.unique(r.row, return_index=True)[1]  # a row's component, from its first entry
    rows = np.bincount(r.component[first], minlength=r.columns.shape[0])
    return bool((rows < r.columns).any())


def outside_held(x: FloatArray, edges: IntArray, bodies: IntArray) -> bool:
    """Whether the first cluster holds every agent outside it: the framework is rigid.

    Every motion is a rigid one plus one that holds the first cluster still, so the
    framework is rigid iff ``R_B`` has full column rank: by the count
    (:func:`unbraced_outside`), then by :func:`full_column_rank`, whose tolerance is
    ``RANK_RTOL`` of ``R_B``'s largest singular value, as the per-component SVDs use their own.
    """
    r = outside_matrix(x, edges, bodies)
    if unbraced_outside(r):
        return False
    shape = (r.rows, int(r.columns.sum()))
    return full_column_rank(csr_matrix((r.value, (r.row, r.column)), shape))
