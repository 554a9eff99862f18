"""Whether a rigid cluster holds the agents outside it, without the whole framework (§2).

Vertex addition on an epoch's kept edges grows a rigid cluster over most agents; the rest,
``U``, are held iff ``R_U`` (their columns, the rows of their edges) has full column rank
(docs/model.md §2, step 4). A count decides most flexible epochs; a sparse stiffness of
``R_U`` alone, far smaller than the whole framework's, decides the others.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import csr_matrix

from formation.graph import BoolArray, FloatArray, IntArray, component_labels
from formation.rigidity import sparse_rigidity_matrix
from formation.rigidity_stiffness import full_column_rank


def unbraced_outside(n: int, d: int, edges: IntArray, cluster: BoolArray) -> bool:
    """Whether a component of the agents outside ``cluster`` has fewer edges than motions.

    ``R_U`` is block diagonal over the components the edges among ``U`` make; a block with
    fewer rows than its ``d`` columns per agent cannot have full column rank: flexible.

    Parameters
    ----------
    n, d : agents and dimension
    edges : (m, 2) int array, agent ids ``1..n``
    cluster : (n,) bool array, the rigid cluster's agents
    """
    e0 = edges - 1
    rest = ~cluster
    labels = component_labels(n, edges, rest[e0[:, 0]] & rest[e0[:, 1]])
    touching = rest[e0[:, 0]] | rest[e0[:, 1]]
    # an edge between U and the cluster is a row of its U agent's component
    owner = np.where(rest[e0[:, 0]], e0[:, 0], e0[:, 1])[touching]
    rows = np.bincount(labels[owner], minlength=n)
    agents = np.bincount(labels[rest], minlength=n)
    return bool((rows < d * agents).any())


def outside_matrix(x: FloatArray, edges: IntArray, cluster: BoolArray) -> csr_matrix:
    """``R_U`` (rows of the edges touching ``U``, ``d`` columns per agent of ``U``), sparse."""
    e0 = edges - 1
    touching = ~(cluster[e0[:, 0]] & cluster[e0[:, 1]])
    r = sparse_rigidity_matrix(x, edges[touching])
    columns = np.flatnonzero(np.repeat(~cluster, x.shape[1]))
    return r[:, columns].tocsr()


def outside_held(x: FloatArray, edges: IntArray, cluster: BoolArray) -> bool:
    """Whether the rigid spanning ``cluster`` holds every agent outside it: the framework is rigid.

    Every motion is a rigid one plus one that is zero on the cluster, so the framework is
    rigid iff ``R_U`` has full column rank (:func:`formation.rigidity_growth.rank_beyond_cluster`):
    by the count (:func:`unbraced_outside`), then by :func:`full_column_rank`, whose
    tolerance is ``RANK_RTOL`` of ``R_U``'s largest singular value, as the per-component
    SVDs use their own.
    """
    n, d = x.shape
    if unbraced_outside(n, d, edges, cluster):
        return False
    return full_column_rank(outside_matrix(x, edges, cluster))
