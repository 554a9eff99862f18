"""Whether a framework is rigid, and its rank, at any size (docs/model.md §2).

Small frameworks by the SVD of :func:`formation.rigidity.rigidity_rank`; large ones by
vertex addition (:mod:`formation.rigidity_growth`), the agents it leaves out by their own
stiffness (:mod:`formation.rigidity_outside`) and, where growth finds no body, the pinned
stiffness (:mod:`formation.rigidity_stiffness`).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from formation.graph import BoolArray, FloatArray, IntArray, as_edge_array, as_positions
from formation.rigidity import SVD_MAX_COLUMNS, expected_rigidity_rank, rigidity_rank
from formation.rigidity_growth import (
    HalfEdges,
    grown_cluster,
    growth_rounds,
    half_edges,
    loose_agent,
    ordered_certificate,
    rank_beyond_cluster,
)
from formation.rigidity_outside import FREE, HELD, outside_held, outside_rank
from formation.rigidity_stiffness import pinned_stiffness_definite


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
    positions: FloatArray,
    edges: IntArray,
    svd_max_columns: int,
    seed: int = 0,
    outside_stiffness: bool = True,
    half: HalfEdges | None = None,
    order: IntArray | None = None,
) -> tuple[int | None, bool]:
    """Rank (None if unknown) and rigidity of a large framework, from vertex addition (§2).

    The rank where :func:`grown_cluster` from edge ``seed`` (or, if it stalls before it has
    ``d + 1`` agents, from the first rounds of ``order``, a growth order on more edges, if
    they are rigid (:func:`rigid_prefix`), or from one of ``SEED_TRIES`` edges spread over
    the list) and
    :func:`rank_beyond_cluster` give it; otherwise only rigid or not. With
    ``outside_stiffness`` the cluster decides that: where it holds fewer than half the
    agents, rigid clusters grown among the others (:func:`further_bodies`) may rank them
    (:func:`outside_rank`); else the agents outside it are held iff their matrix ``R_B``
    has full column rank (:func:`outside_held`). Without (the
    benchmark's baseline), or where growth found no body, the whole framework's
    :func:`pinned_stiffness_definite` does. ``half``: the :class:`HalfEdges` of ``edges``,
    if known.
    """
    need = expected_rigidity_rank(*positions.shape)
    d = positions.shape[1]
    half = half_edges(positions, edges - 1) if half is None else half
    cluster = grown_cluster(positions, edges, seed, half)
    body = (
        rigid_prefix(positions, edges, order) if cluster.sum() <= d and order is not None else None
    )
    if body is not None:
        cluster = growth_rounds(positions, edges, half=half, body=body) >= 0
    tries = np.linspace(0, edges.shape[0] - 1, SEED_TRIES).astype(np.int64)
    for other in tries if cluster.sum() <= d else ():  # stalled at the simplex: elsewhere
        cluster = grown_cluster(positions, edges, int(other), half)
        if cluster.sum() > d:
            break
    if cluster.all():
        return need, True
    rank = rank_beyond_cluster(positions, edges, cluster, svd_max_columns)
    if rank is not None:
        return rank, rank == need
    if edges.shape[0] < need:
        return None, False
    if outside_stiffness and cluster.sum() > d:  # a body: only the agents outside it
        bodies = np.where(cluster, HELD, FREE)
        if cluster.sum() * 2 < cluster.shape[0]:  # most agents outside: worth more bodies
            bodies = further_bodies(positions, edges, cluster, half)
        if bodies.max() > HELD:
            rank = outside_rank(positions, edges, bodies, min(svd_max_columns, BODY_SVD_COLUMNS))
            if rank is not None:
                return rank, rank == need
        rigid = outside_held(positions, edges, bodies)
        return (need if rigid else None), rigid
    rigid = pinned_stiffness_definite(positions, edges)
    return (need if rigid else None), rigid


BODY_SVD_COLUMNS = 120
"""Components of ``R_B`` up to this many columns are ranked by the dense SVD where further
clusters were grown; a larger one goes to the sparse check, which costs less per epoch."""


def further_bodies(
    positions: FloatArray, edges: IntArray, cluster: BoolArray, half: HalfEdges
) -> IntArray:
    """Body labels (:mod:`formation.rigidity_outside`): ``cluster`` :data:`HELD`, the rigid
    clusters grown among the agents outside it ``1, 2, …``, the rest :data:`FREE`.

    ``SEED_TRIES`` growths, each on the edges among the agents in no cluster yet, from one
    of those edges spread over their list; a cluster of more than ``d`` agents spans the
    space (it started from a simplex) and is kept. Disjoint, so each is rigid alone.
    ``half``: the :class:`HalfEdges` of ``edges``.
    """
    d = positions.shape[1]
    e0 = edges - 1
    bodies = np.where(cluster, HELD, FREE)
    for attempt in range(SEED_TRIES):
        free = bodies == FREE
        among = free[e0[:, 0]] & free[e0[:, 1]]
        count = int(among.sum())
        if count < d * (d + 1) // 2:  # fewer edges than a simplex has
            break
        seed = (2 * attempt + 1) * count // (2 * SEED_TRIES)
        grown = growth_rounds(positions, edges[among], seed, half.kept(among)) >= 0
        if grown.sum() > d:
            bodies[grown] = bodies.max() + 1
    return bodies


def rank_under_mask(
    positions: FloatArray,
    edges: IntArray,
    rounds: IntArray,
    mask: BoolArray,
    spread: bool,
    svd_max_columns: int = SVD_MAX_COLUMNS,
    outside_stiffness: bool = True,
    half: HalfEdges | None = None,
) -> tuple[int | None, bool]:
    """Rank (None if unknown) and rigidity of the kept edges, the growth order known (§2).

    The order grown once on all edges, checked again (:func:`ordered_certificate`); an
    agent whose kept edges do not span the space (:func:`loose_agent`, valid when
    ``spread``: :func:`spans_without_any` of ``positions``); else growth again on the kept
    edges from the same seed (:func:`rank_beyond_growth`, ``outside_stiffness`` passed on).
    ``half``: the :class:`HalfEdges` of all ``edges``, if known (a formation's, kept).
    """
    need = expected_rigidity_rank(*positions.shape)
    half = half_edges(positions, edges - 1) if half is None else half
    halves = half.kept(mask)  # the kept edges' half-edges, once for the three steps
    if ordered_certificate(positions, edges, rounds, mask, halves):
        return need, True
    if spread and loose_agent(positions, edges, mask, halves):
        return None, False
    kept = edges[mask]
    seeds = np.flatnonzero((rounds[kept[:, 0] - 1] == 0) & (rounds[kept[:, 1] - 1] == 0))
    seed = int(seeds[0]) if seeds.size else 0  # the growth order's own seed edge, if kept
    return rank_beyond_growth(
        positions, kept, svd_max_columns, seed, outside_stiffness, halves, order=rounds
    )


def rigid_prefix(positions: FloatArray, edges: IntArray, order: IntArray) -> BoolArray | None:
    """The agents of the first rounds of a growth ``order`` if their ``edges`` make them rigid.

    The smallest prefix of whole rounds with ``2(d + 1)``, ``4(d + 1)`` or ``8(d + 1)``
    agents whose edges among them have the expected rank by the dense SVD (at most
    ``SVD_MAX_COLUMNS`` columns): a rigid body that spans the space, which growth may
    start from where the seed's simplex lost an edge. None if no such prefix is rigid.
    """
    d = positions.shape[1]
    joined = np.sort(order[order >= 0])
    e0 = edges - 1
    for size in (2 * (d + 1), 4 * (d + 1), 8 * (d + 1)):
        if size > joined.shape[0]:
            break
        body: BoolArray = (order >= 0) & (order <= joined[size - 1])
        count = int(body.sum())
        if count * d > SVD_MAX_COLUMNS:
            break
        among = body[e0[:, 0]] & body[e0[:, 1]]
        within = np.cumsum(body)  # an agent's id within the body, from 1
        if rigidity_rank(positions[body], within[e0[among]]) == expected_rigidity_rank(count, d):
            return body
    return None
