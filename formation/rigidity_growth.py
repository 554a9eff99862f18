"""Rigidity of large frameworks by vertex addition: a rigid cluster grown edge by edge (§2).

A cluster of every agent certifies rigidity; the agents it leaves out are ranked alone
(:func:`rank_beyond_cluster`); the growth order, found once, checks a formation's
kept edges of each epoch again (:func:`ordered_certificate`). All at ``positions``, in
rounds of array work.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from formation.graph import (
    BoolArray,
    FloatArray,
    IntArray,
    as_edge_array,
    as_edge_mask,
    as_positions,
)
from formation.rigidity import (
    RANK_RTOL,
    SVD_MAX_COLUMNS,
    batched_ranks,
    expected_rigidity_rank,
)
from formation.rigidity_outside import FREE, HELD, outside_rank


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


def loose_agent(
    positions: npt.ArrayLike,
    edges: npt.ArrayLike,
    mask: npt.ArrayLike,
    kept: HalfEdges | None = None,
) -> bool:
    """Whether some agent's kept edges leave a direction free: fewer than ``d`` independent ones.

    That agent alone can move across all its edges, a motion that is not rigid when the
    others span the space (:func:`spans_without_any`): the framework is flexible. ``kept``:
    the :class:`HalfEdges` of the kept edges, if known.
    """
    x = as_positions(positions)
    n, d = x.shape
    e0 = as_edge_array(n, edges) - 1
    keep = as_edge_mask(mask, e0.shape[0])
    kept = half_edges(x, e0[keep]) if kept is None else kept
    count = np.diff(kept.start)
    if (count < d).any():
        return True
    return bool((_unit_ranks(kept.dirs, np.arange(kept.tail.shape[0]), count) < d).any())


class HalfEdges(NamedTuple):
    """Both directions of each edge, sorted by tail (CSR-like), with their unit directions."""

    tail: IntArray
    head: IntArray
    start: IntArray
    """(n + 1,): agent ``a``'s half-edges are ``start[a]:start[a + 1]``."""
    edge: IntArray
    """The edge each half-edge is a direction of."""
    dirs: FloatArray
    """Unit directions ``tail → head``, a zero row last (:func:`_unit_directions`)."""

    def kept(self, keep: BoolArray) -> HalfEdges:
        """The half-edges of the edges ``keep`` selects, as :func:`half_edges` of them gives.

        The same order (a stable sort, filtered) and the same directions, row by row.
        """
        sel = np.flatnonzero(keep[self.edge])
        tail = self.tail[sel]
        start = np.searchsorted(tail, np.arange(self.start.shape[0]))
        edge = np.cumsum(keep) - 1  # an edge's index among the kept
        return HalfEdges(
            tail, self.head[sel], start, edge[self.edge[sel]], self.dirs[np.append(sel, -1)]
        )


def half_edges(x: FloatArray, e0: IntArray) -> HalfEdges:
    """The :class:`HalfEdges` of 0-based edges ``e0`` (m, 2) between agents at ``x`` (n, d)."""
    tail, head, start, edge = _half_edges(x.shape[0], e0)
    return HalfEdges(tail, head, start, edge, _unit_directions(x, tail, head))


def _half_edges(n: int, e0: IntArray) -> tuple[IntArray, IntArray, IntArray, IntArray]:
    """Both directions of each 0-based edge, sorted by tail: ``(tail, head, start, edge)``."""
    tail = np.concatenate([e0[:, 0], e0[:, 1]])
    head = np.concatenate([e0[:, 1], e0[:, 0]])
    # 16-bit keys take numpy's radix sort: the same stable order, ten times sooner
    order = np.argsort(tail.astype(np.uint16) if n <= 1 << 16 else tail, kind="stable")
    tail = tail[order]
    edge = order % max(e0.shape[0], 1)
    return tail, head[order], np.searchsorted(tail, np.arange(n + 1)), edge


def _direction_ranks(x: FloatArray, tail: IntArray, head: IntArray, counts: IntArray) -> IntArray:
    """Rank of each candidate's edge directions; its half-edges are consecutive, ``counts`` each."""
    return _unit_ranks(_unit_directions(x, tail, head), np.arange(tail.shape[0]), counts)


def _unit_directions(x: FloatArray, tail: IntArray, head: IntArray) -> FloatArray:
    """Unit directions ``tail → head`` (lengths never matter, only angles), a zero row last."""
    dirs = np.empty((tail.shape[0] + 1, x.shape[1]))
    dirs[:-1] = x[head] - x[tail]
    dirs[:-1] /= np.linalg.norm(dirs[:-1], axis=1, keepdims=True)
    dirs[-1] = 0.0  # index -1: the padding
    return dirs


def _unit_ranks(dirs: FloatArray, index: IntArray, counts: IntArray) -> IntArray:
    """Rank of each candidate's rows ``dirs[index]``, consecutive in ``index``, ``counts`` each.

    Those :func:`_surely_spanning` passes have rank ``d``; the others are stacked by counts
    rounded up to a power of two, zero rows padding the rest (they change no singular
    value): a few batched SVDs, not one per count.
    """
    d = dirs.shape[1]
    out = np.zeros(counts.shape[0], dtype=np.int64)
    first = counts.cumsum() - counts
    padded = np.concatenate([index, [-1]])  # past the end: the zero row
    sure = _surely_spanning(dirs, padded, first, counts)
    if sure.all():  # the common case: no SVD
        return np.full(counts.shape[0], d, dtype=np.int64)
    out[sure] = d
    width = 1 << np.ceil(np.log2(np.maximum(counts, 1))).astype(np.int64)
    width[sure] = 0
    for k in np.unique(width[width > 0]):
        sel = np.flatnonzero(width == k)
        rows = first[sel, None] + np.arange(k)
        rows[np.arange(k) >= counts[sel, None]] = index.shape[0]
        out[sel] = batched_ranks(dirs[padded[rows]])
    return out


def _surely_spanning(
    dirs: FloatArray, padded: IntArray, first: IntArray, counts: IntArray
) -> BoolArray:
    """Candidates whose unit directions surely have rank ``d`` at the SVD's tolerance, no SVD.

    Of a candidate's first ``d + 1`` directions, ``d`` whose determinant ``δ`` is largest
    form ``S``: ``σ_d(S) ≥ |δ| / σ_1(S)^(d−1) ≥ |δ| / d^((d−1)/2)`` (unit rows). All ``c`` rows
    ``A`` hold ``S``, so ``σ_d(A) ≥ σ_d(S)``, and ``σ_1(A) ≤ ‖A‖_F = √c``: when
    ``|δ| > RANK_RTOL · √c · d^((d−1)/2)``, ``σ_d(A) > RANK_RTOL · σ_1(A)``, the SVD's
    rank ``d``. The rest (a determinant near zero) go to the SVD.
    """
    d = dirs.shape[1]
    if d not in (2, 3):
        return np.zeros(counts.shape[0], dtype=bool)
    rows = first[:, None] + np.arange(d + 1)
    rows[np.arange(d + 1) >= counts[:, None]] = padded.shape[0] - 1  # the zero row: δ = 0
    best = _largest_determinants(dirs[padded[rows]])
    sure: BoolArray = best > RANK_RTOL * np.sqrt(counts) * d ** ((d - 1) / 2)
    return sure


def _largest_determinants(s: FloatArray) -> FloatArray:
    """The largest ``|δ|`` of ``d`` of each stack's ``d + 1`` rows: ``(B, d + 1, d)`` → ``(B,)``."""
    if s.shape[2] == 2:
        a, b = s[:, [0, 0, 1]], s[:, [1, 2, 2]]
        best: FloatArray = np.abs(a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]).max(axis=1)
        return best
    a, b, c = s[:, [0, 0, 0, 1]], s[:, [1, 1, 2, 2]], s[:, [2, 3, 3, 3]]
    det = (
        a[..., 0] * (b[..., 1] * c[..., 2] - b[..., 2] * c[..., 1])
        - a[..., 1] * (b[..., 0] * c[..., 2] - b[..., 2] * c[..., 0])
        + a[..., 2] * (b[..., 0] * c[..., 1] - b[..., 1] * c[..., 0])
    )
    best = np.abs(det).max(axis=1)
    return best


def grown_cluster(
    positions: npt.ArrayLike, edges: npt.ArrayLike, seed: int = 0, half: HalfEdges | None = None
) -> BoolArray:
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
    return growth_rounds(positions, edges, seed, half) >= 0


def growth_rounds(
    positions: npt.ArrayLike,
    edges: npt.ArrayLike,
    seed: int = 0,
    half: HalfEdges | None = None,
    body: BoolArray | None = None,
) -> IntArray:
    """The round at which each agent joined :func:`grown_cluster`'s cluster, −1 if never.

    The seed edge's two agents join at round 0; agents of one round joined the cluster of
    the rounds before it, which is what :func:`ordered_certificate` checks again. Past the
    simplex only agents next to the last round's are examined: no other's edges into the
    cluster changed, so ``O(m)`` work in all. ``half``: the :class:`HalfEdges` of ``edges``,
    if known. ``body``: instead of the seed edge, agents known to be a rigid cluster that
    spans the space (round 0). The rounds run compiled
    (:mod:`formation.compiled_growth`); candidates the determinant bound leaves take
    the batched SVD here, as in :func:`reference_growth_rounds`, whose answer this is.
    """
    x = as_positions(positions)
    n, d = x.shape
    e0 = as_edge_array(n, edges) - 1
    rounds = np.full(n, -1, dtype=np.int64)
    if e0.shape[0] == 0:
        return rounds
    _, head, start, _, dirs = half_edges(x, e0) if half is None else half
    # numba takes about a second to load: only once a framework grows (large ones)
    from formation.compiled_growth import DONE, grow

    head, start = head.astype(np.int64, copy=False), start.astype(np.int64, copy=False)
    dirs = np.ascontiguousarray(dirs, dtype=np.float64)
    inside = np.zeros(n, dtype=bool)
    count = np.zeros(n, dtype=np.int64)  # edges into the cluster
    stamp = np.zeros(n, dtype=np.int64)
    near = np.empty(head.shape[0], dtype=np.int64)
    cand = np.empty(n, dtype=np.int64)
    sure = np.empty(n, dtype=bool)
    added = np.empty(n, dtype=np.int64)
    joined = np.unique(e0[seed]) if body is None else np.flatnonzero(body)
    k, size = 0, 0
    scale = float(d ** ((d - 1) / 2)) if d in (2, 3) else -1.0
    while True:
        added[: joined.shape[0]] = joined
        status, k, size, found = grow(
            added,
            joined.shape[0],
            k,
            size,
            head,
            start,
            dirs,
            scale,
            rounds,
            inside,
            count,
            stamp,
            near,
            cand,
            sure,
        )
        if status == DONE:
            break
        # the candidates the bound left, by the SVD: the reference's ranks
        passed = sure[:found].copy()
        unsure = cand[:found][~passed]
        into = _slices(start, unsure)
        into = into[inside[head[into]]]
        passed[~passed] = _unit_ranks(dirs, into, count[unsure]) >= min(d, size)
        joined = cand[:found][passed]
        if size <= d:
            joined = joined[:1]  # a simplex grows one agent at a time
        if joined.shape[0] == 0:
            break
    return rounds


def reference_growth_rounds(
    positions: npt.ArrayLike,
    edges: npt.ArrayLike,
    seed: int = 0,
    half: HalfEdges | None = None,
    body: BoolArray | None = None,
) -> IntArray:
    """:func:`growth_rounds` in rounds of numpy: the reference the compiled rounds are held to."""
    x = as_positions(positions)
    n, d = x.shape
    e0 = as_edge_array(n, edges) - 1
    rounds = np.full(n, -1, dtype=np.int64)
    if e0.shape[0] == 0:
        return rounds
    tail, head, start, _, dirs = half_edges(x, e0) if half is None else half
    inside = np.zeros(n, dtype=bool)
    count = np.zeros(n, dtype=np.int64)  # edges into the cluster
    stamp = np.zeros(n, dtype=np.int64)
    places = np.arange(tail.shape[0])
    added = np.unique(e0[seed]) if body is None else np.flatnonzero(body)
    size, k = 0, 0
    while True:
        rounds[added] = k
        inside[added] = True
        size += added.shape[0]
        if size == n:
            break
        near = head[_slices(start, added)]
        np.add.at(count, near, 1)
        k += 1
        if size <= d:  # the simplex: one agent joined to all of it
            cand = np.flatnonzero(~inside & (count == size))
        elif size - added.shape[0] <= d:  # the simplex just done: every agent may join
            cand = np.flatnonzero(~inside & (count >= d))
        else:  # only the last round's neighbours gained edges into the cluster
            near = near[(count[near] >= d) & ~inside[near]]
            stamp[near] = places[: near.shape[0]]
            cand = near[stamp[near] == places[: near.shape[0]]]  # each agent once
        if cand.shape[0] == 0:
            break
        into = _slices(start, cand)
        into = into[inside[head[into]]]
        added = cand[_unit_ranks(dirs, into, count[cand]) >= min(d, size)]
        if size <= d:
            added = added[:1]  # a simplex grows one agent at a time, each off the others' hull
        if added.shape[0] == 0:
            break
    return rounds


def _slices(start: IntArray, agents: IntArray) -> IntArray:
    """Indices of the half-edges of ``agents`` (CSR ``start``), agent after agent."""
    lo = start[agents]
    lengths = start[agents + 1] - lo
    ends = lengths.cumsum()
    out: IntArray = np.repeat(lo - ends + lengths, lengths) + np.arange(
        ends[-1] if ends.size else 0
    )
    return out


def ordered_certificate(
    positions: npt.ArrayLike,
    edges: npt.ArrayLike,
    rounds: IntArray,
    mask: npt.ArrayLike,
    kept: HalfEdges | None = None,
) -> bool:
    """Whether the edges in ``mask`` still attach every agent as :func:`growth_rounds` did (§2).

    Each agent of round ``k`` needs, among its kept edges to agents of earlier rounds,
    ``d`` along independent directions (in the first rounds, while the cluster has at
    most ``d`` agents: an edge to each of them, independent). True proves the kept
    graph rigid at ``positions``; False proves nothing. One pass of array work, so a
    formation's epochs reuse the order grown once on all its edges. ``kept``: the
    :class:`HalfEdges` of the kept edges, if known.
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
    kept = half_edges(x, e0[keep]) if kept is None else kept
    tail, head = kept.tail, kept.head
    back = rounds[head] < rounds[tail]
    count = np.bincount(tail[back], minlength=n)
    before = np.searchsorted(np.sort(rounds), rounds)  # agents in earlier rounds
    need = np.minimum(d, before)
    small = before <= d
    if (count[small] != before[small]).any() or (count < need).any():
        return False
    late = np.flatnonzero(before > 0)
    ranks = _unit_ranks(kept.dirs, np.flatnonzero(back), count[late]) if late.size else late
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
    if inside.all():
        return expected_rigidity_rank(n, d)
    return outside_rank(x, e0 + 1, np.where(inside, HELD, FREE), max_columns)
