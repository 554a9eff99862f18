"""Rigidity of a framework: the rigidity matrix, its rank, and the checks that scale (docs/model.md §2).

Small frameworks are checked by the dense SVD; large ones by growth of rigid clusters,
an ordered certificate, and the pinned stiffness's weakest motions (step 5), each against
the same rank tolerance :data:`RANK_RTOL`. The scenario loader checks its shape with it;
the leader re-exports it (``leader.rigidity``).
"""

from __future__ import annotations

import operator

import numpy as np
import numpy.typing as npt
from scipy.sparse import csr_matrix
from scipy.sparse.linalg import splu

from formation.graph import (
    BoolArray,
    FloatArray,
    GraphInputError,
    IntArray,
    as_edge_array,
    as_edge_mask,
    as_positions,
    check_agent_count,
    component_labels,
)

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

INVERSE_STEPS = 4
"""Steps of block inverse iteration that find the pinned stiffness's weakest motions."""

INVERSE_BLOCK = 3
"""Vectors of that block: the weakest motion is found in it even when the pinning mixes
the order of a few nearly as weak ones."""


def is_rigid(
    positions: npt.ArrayLike, edges: npt.ArrayLike, svd_max_columns: int = SVD_MAX_COLUMNS
) -> bool:
    """Whether the framework is infinitesimally rigid: rank ``R(q)`` = the expected rank (§2).

    Small frameworks (``n·d ≤ svd_max_columns``) by the SVD of :func:`rigidity_rank`. Larger
    ones without the edge count are not rigid; the others are rigid if vertex addition
    grows one rigid cluster over every agent (:func:`grown_cluster`), otherwise by the SVD
    of the agents it left out if they are few (:func:`rank_beyond_cluster`), and otherwise
    by whether the pinned stiffness ``RᵀR + CᵀC`` is positive definite
    (:func:`pinned_stiffness_definite`). All are evaluated at ``positions``, not at
    generic ones, so grids and collinear agents get their own answer.
    """
    x = as_positions(positions)
    n, d = x.shape
    e = as_edge_array(n, edges)
    need = expected_rigidity_rank(n, d)
    if n * d <= svd_max_columns or n <= d + 1:
        return rigidity_rank(x, e) == need
    if e.shape[0] < need:
        return False
    return rank_beyond_growth(x, e, svd_max_columns)[1]


SEED_TRIES = 8
"""Seed edges :func:`rank_beyond_growth` tries when growth stalls before it has a body."""


def rank_beyond_growth(
    positions: FloatArray, edges: IntArray, svd_max_columns: int, seed: int = 0
) -> tuple[int | None, bool]:
    """Rank (None if unknown) and rigidity of a large framework, from vertex addition (§2).

    The rank where :func:`grown_cluster` from edge ``seed`` (or, if it stalls before it has
    ``d + 1`` agents, from one of ``SEED_TRIES`` edges spread over the list) and
    :func:`rank_beyond_cluster` give it; otherwise only rigid or not, by
    :func:`pinned_stiffness_definite`.
    """
    need = expected_rigidity_rank(*positions.shape)
    d = positions.shape[1]
    cluster = grown_cluster(positions, edges, seed)
    tries = np.linspace(0, edges.shape[0] - 1, SEED_TRIES).astype(np.int64)
    for other in tries if cluster.sum() <= d else ():  # stalled at the simplex: elsewhere
        cluster = grown_cluster(positions, edges, int(other))
        if cluster.sum() > d:
            break
    if cluster.all():
        return need, True
    rank = rank_beyond_cluster(positions, edges, cluster, svd_max_columns)
    if rank is not None:
        return rank, rank == need
    if edges.shape[0] < need:
        return None, False
    rigid = pinned_stiffness_definite(positions, edges)
    return (need if rigid else None), rigid


def rank_under_mask(
    positions: FloatArray,
    edges: IntArray,
    rounds: IntArray,
    mask: BoolArray,
    spread: bool,
    svd_max_columns: int = SVD_MAX_COLUMNS,
) -> tuple[int | None, bool]:
    """Rank (None if unknown) and rigidity of the kept edges, the growth order known (§2).

    The order grown once on all edges, checked again (:func:`ordered_certificate`); an
    agent whose kept edges do not span the space (:func:`loose_agent`, valid when
    ``spread``: :func:`spans_without_any` of ``positions``); else growth again on the kept
    edges from the same seed (:func:`rank_beyond_growth`).
    """
    need = expected_rigidity_rank(*positions.shape)
    if ordered_certificate(positions, edges, rounds, mask):
        return need, True
    if spread and loose_agent(positions, edges, mask):
        return None, False
    kept = edges[mask]
    seeds = np.flatnonzero((rounds[kept[:, 0] - 1] == 0) & (rounds[kept[:, 1] - 1] == 0))
    seed = int(seeds[0]) if seeds.size else 0  # the growth order's own seed edge, if kept
    return rank_beyond_growth(positions, kept, svd_max_columns, seed)


def spans_without_any(positions: npt.ArrayLike) -> bool:
    """Whether the agents less any one of them still span the space affinely.

    True when two disjoint sets of ``d + 1`` agents are each affinely independent: every
    agent misses one of them. Then a motion that moves one agent alone is never rigid.
    """
    x = as_positions(positions)
    n, d = x.shape
    free = np.ones(n, dtype=bool)
    for _ in range(2):
        if free.sum() < d + 1:
            return False
        chosen = [int(np.flatnonzero(free)[0])]
        for _k in range(d):
            rel = x - x[chosen[0]]
            basis = rel[chosen[1:]]
            if basis.shape[0]:
                q = np.linalg.qr(basis.T)[0]
                rel = rel - rel @ q @ q.T
            dist = np.where(free, np.linalg.norm(rel, axis=1), -1.0)
            dist[chosen] = -1.0
            best = int(np.argmax(dist))
            if dist[best] <= RANK_RTOL * max(float(np.ptp(x, axis=0).max()), 1e-300):
                return False
            chosen.append(best)
        free[chosen] = False
    return True


def loose_agent(positions: npt.ArrayLike, edges: npt.ArrayLike, mask: npt.ArrayLike) -> bool:
    """Whether some agent's kept edges leave a direction free: fewer than ``d`` independent ones.

    That agent alone can move across all its edges, a motion that is not rigid when the
    others span the space (:func:`spans_without_any`): the framework is flexible.
    """
    x = as_positions(positions)
    n, d = x.shape
    e0 = as_edge_array(n, edges) - 1
    keep = as_edge_mask(mask, e0.shape[0])
    tail, head, start = _half_edges(n, e0[keep])
    count = np.diff(start)
    if (count < d).any():
        return True
    return bool((_direction_ranks(x, tail, head, count) < d).any())


def _half_edges(n: int, e0: IntArray) -> tuple[IntArray, IntArray, IntArray]:
    """Both directions of each 0-based edge, sorted by tail: ``(tail, head, start)``, CSR-like."""
    tail = np.concatenate([e0[:, 0], e0[:, 1]])
    head = np.concatenate([e0[:, 1], e0[:, 0]])
    order = np.argsort(tail, kind="stable")
    return tail[order], head[order], np.searchsorted(tail[order], np.arange(n + 1))


def _direction_ranks(x: FloatArray, tail: IntArray, head: IntArray, counts: IntArray) -> IntArray:
    """Rank of each candidate's edge directions; its half-edges are consecutive, ``counts`` each.

    Candidates are stacked by counts rounded up to a power of two, zero rows padding the
    rest (they change no singular value): a few batched SVDs, not one per count.
    """
    out = np.zeros(counts.shape[0], dtype=np.int64)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    dirs = x[head] - x[tail]
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)  # lengths never matter, only angles
    dirs = np.vstack([dirs, np.zeros((1, x.shape[1]))])  # row -1: the padding
    width = 1 << np.ceil(np.log2(np.maximum(counts, 1))).astype(np.int64)
    for k in np.unique(width):
        sel = np.flatnonzero(width == k)
        rows = first[sel, None] + np.arange(k)
        rows[np.arange(k) >= counts[sel, None]] = -1
        out[sel] = _batched_ranks(dirs[rows])
    return out


def grown_cluster(positions: npt.ArrayLike, edges: npt.ArrayLike, seed: int = 0) -> BoolArray:
    """The agents of the rigid cluster that vertex addition grows from edge ``seed`` (§2).

    A cluster of ``c ≤ d`` agents affinely independent and all joined takes an agent joined to
    all of them, off their affine hull; a larger one takes, all at once, every agent with
    ``d`` edges into it along independent directions. Each step keeps the cluster
    infinitesimally rigid at ``positions`` (the agent's velocity is fixed by ``d``
    independent constraints against a rigid body), so a cluster of every agent is a
    certificate of rigidity; a smaller one proves nothing. Rounds of array work, ``O(m)``
    each.

    Returns
    -------
    (n,) bool: the cluster's agents (none if there are no edges).
    """
    return growth_rounds(positions, edges, seed) >= 0


def growth_rounds(positions: npt.ArrayLike, edges: npt.ArrayLike, seed: int = 0) -> IntArray:
    """The round at which each agent joined :func:`grown_cluster`'s cluster, −1 if never.

    The seed edge's two agents join at round 0; agents of one round joined the cluster of
    the rounds before it, which is what :func:`ordered_certificate` checks again. Past the
    simplex only agents next to the last round's are examined: no other's edges into the
    cluster changed, so ``O(m)`` work in all.
    """
    x = as_positions(positions)
    n, d = x.shape
    e0 = as_edge_array(n, edges) - 1
    rounds = np.full(n, -1, dtype=np.int64)
    if e0.shape[0] == 0:
        return rounds
    tail, head, start = _half_edges(n, e0)
    inside = np.zeros(n, dtype=bool)
    count = np.zeros(n, dtype=np.int64)  # edges into the cluster
    added = np.unique(e0[seed])
    size, k, was_simplex = 0, 0, True
    while added.shape[0]:
        rounds[added] = k
        inside[added] = True
        size += added.shape[0]
        if size == n:
            break
        out_of_new = _slices(start, added)
        np.add.at(count, head[out_of_new], 1)
        k += 1
        need = min(d, size)
        if was_simplex:
            outside = np.flatnonzero(~inside)
        else:
            outside = np.unique(head[out_of_new])
            outside = outside[~inside[outside]]
        joined_to = count[outside]
        cand = outside[joined_to == size] if size <= d else outside[joined_to >= need]
        was_simplex = size <= d
        if cand.shape[0] == 0:
            break
        into = _slices(start, cand)
        into = into[inside[head[into]]]
        ranks = _direction_ranks(x, tail[into], head[into], count[cand])
        added = cand[ranks >= need]
        if size <= d:
            added = added[:1]  # a simplex grows one agent at a time, each off the others' hull
    return rounds


def _slices(start: IntArray, agents: IntArray) -> IntArray:
    """Indices of the half-edges of ``agents`` (CSR ``start``), agent after agent."""
    lo, hi = start[agents], start[agents + 1]
    lengths = hi - lo
    offsets = np.arange(lengths.sum()) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    out: IntArray = np.repeat(lo, lengths) + offsets
    return out


def ordered_certificate(
    positions: npt.ArrayLike, edges: npt.ArrayLike, rounds: IntArray, mask: npt.ArrayLike
) -> bool:
    """Whether the edges in ``mask`` still attach every agent as :func:`growth_rounds` did (§2).

    Each agent of round ``k`` needs, among its kept edges to agents of earlier rounds,
    ``d`` along independent directions (in the first rounds, while the cluster has at
    most ``d`` agents: an edge to each of them, independent). True proves the kept
    graph rigid at ``positions``; False proves nothing. One pass of array work, so a
    formation's epochs reuse the order grown once on all its edges.
    """
    x = as_positions(positions)
    n, d = x.shape
    e0 = as_edge_array(n, edges) - 1
    keep = as_edge_mask(mask, e0.shape[0])
    if (rounds < 0).any():
        return False
    first = (rounds[e0[:, 0]] == 0) & (rounds[e0[:, 1]] == 0)
    if not (keep & first).any():
        return False  # the seed edge, the first rigid body, is lost
    tail, head, _ = _half_edges(n, e0[keep])
    back = rounds[head] < rounds[tail]
    count = np.bincount(tail[back], minlength=n)
    before = np.searchsorted(np.sort(rounds), rounds)  # agents in earlier rounds
    need = np.minimum(d, before)
    small = before <= d
    if (count[small] != before[small]).any() or (count < need).any():
        return False
    late = np.flatnonzero(before > 0)
    ranks = _direction_ranks(x, tail[back], head[back], count[late]) if late.size else late
    return bool((ranks >= need[late]).all())


def rank_beyond_cluster(
    positions: npt.ArrayLike,
    edges: npt.ArrayLike,
    cluster: npt.ArrayLike,
    max_columns: int = SVD_MAX_COLUMNS,
) -> int | None:
    """``rank R(q)`` from a rigid cluster and SVDs of the agents outside it, or None.

    ``cluster`` must be infinitesimally rigid and span the space, as :func:`grown_cluster`'s
    is once it has more than ``d`` agents. Every motion is then a rigid motion plus one that is zero on the cluster, so
    ``rank R = expected(n, d) − |U|·d + rank R_U``, ``R_U`` the columns of the agents ``U``
    outside the cluster in the rows of their edges. ``R_U`` is block diagonal over the
    components that the edges among ``U`` make, so each is ranked alone. None when the
    cluster has at most ``d`` agents or a component has more than ``max_columns`` columns.
    """
    x = as_positions(positions)
    n, d = x.shape
    e0 = as_edge_array(n, edges) - 1
    inside = as_edge_mask(cluster, n, "cluster")
    if inside.sum() <= d:
        return None
    rest = np.flatnonzero(~inside)
    if rest.size == 0:
        return expected_rigidity_rank(n, d)
    among = ~inside[e0[:, 0]] & ~inside[e0[:, 1]]
    _, component, size = np.unique(
        component_labels(n, e0 + 1, among)[rest], return_inverse=True, return_counts=True
    )
    if size.max() * d > max_columns:
        return None
    of_agent = np.full(n, -1, dtype=np.int64)  # component of each agent outside
    of_agent[rest] = component
    place = np.zeros(n, dtype=np.int64)  # an agent's place within its component
    order = np.argsort(component, kind="stable")
    place[rest[order]] = np.arange(rest.size) - np.searchsorted(component[order], component[order])
    touching = ~(inside[e0[:, 0]] & inside[e0[:, 1]])
    r = sparse_rigidity_matrix(x, e0[touching] + 1).tocoo()
    agent = r.col // d
    outside = of_agent[agent] >= 0  # entries in the columns of U
    row, agent, col, value = r.row[outside], agent[outside], r.col[outside] % d, r.data[outside]
    comp = of_agent[agent]
    rank = 0
    for k in np.unique(size):  # a dense stack per component size, one batched SVD each
        chosen = size[comp] == k
        if not chosen.any():
            continue  # components without a kept edge: rank 0
        slot = np.cumsum(size == k) - 1  # component → its index in the stack
        c = slot[comp[chosen]]
        # rows numbered within their component
        key = c.astype(np.int64) * (r.shape[0] + 1) + row[chosen]
        uniq, inverse = np.unique(key, return_inverse=True)
        owner = uniq // (r.shape[0] + 1)
        local = np.arange(uniq.size) - np.searchsorted(owner, owner)
        stack = np.zeros((int((size == k).sum()), int(local.max()) + 1, int(k) * d))
        stack[c, local[inverse], place[agent[chosen]] * d + col[chosen]] = value[chosen]
        rank += int(_batched_ranks(stack).sum())
    return int(expected_rigidity_rank(n, d) - int(rest.size) * d + rank)


def _batched_ranks(blocks: FloatArray) -> IntArray:
    """:func:`_svd_rank` of each matrix of a stack ``(B, r, c)``."""
    s = np.linalg.svd(blocks, compute_uv=False)
    top = s[:, :1]
    ranks: IntArray = np.count_nonzero((s > RANK_RTOL * top) & (top > 0), axis=1)
    return ranks


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
    c = csr_matrix(pins)
    k = (r.T @ r + c.T @ c).tocsc()
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
    motions = _rigid_motions(x)
    weak = np.linalg.qr(np.hstack([motions, y]))[0][:, motions.shape[1] :]
    weakest = np.linalg.svd(r @ weak, compute_uv=False)[-1]
    return bool(weakest > RANK_RTOL * _largest_singular_value(r))


def _rigid_motions(x: FloatArray) -> FloatArray:
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
