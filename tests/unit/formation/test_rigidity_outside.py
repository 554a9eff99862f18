"""A grown cluster and the agents outside it give the dense SVD's rank, on every team family.

``svd_max_columns=0`` sends teams small enough for the SVD down the large-formation path;
the SVD of the whole rigidity matrix is the reference (docs/model.md §2).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from formation.errors import ScenarioError
from formation.rigidity import expected_rigidity_rank, rigidity_rank, sparse_rigidity_matrix
from formation.rigidity_check import further_bodies, rank_under_mask
from formation.rigidity_growth import (
    grown_cluster,
    growth_rounds,
    half_edges,
    rank_beyond_cluster,
    spans_without_any,
)
from formation.rigidity_outside import (
    FREE,
    HELD,
    outside_held,
    outside_matrix,
    outside_rank,
    unbraced_outside,
)
from formation.rigidity_stiffness import full_column_rank
from formation.scenario import Scenario
from testbed.sim.team_generators import geometric_team, henneberg_team, rigid_team


def family(name: str, n: int, d: int, redundancy: float, seed: int) -> Scenario:
    if name == "henneberg":
        return henneberg_team(n, seed=seed, redundancy=redundancy)
    if name == "rigid_team":
        return rigid_team(n, d, redundancy, seed=seed)
    try:
        return geometric_team(n, d, redundancy, seed=seed)
    except ScenarioError:
        # without spare edges a geometric team of a hundred agents in space is sometimes
        # flexible to rounding (its smallest singular value ~1e-10 of the largest): no team
        assume(False)
        raise


@settings(max_examples=15, deadline=None)
@given(
    name=st.sampled_from(["henneberg", "rigid_team", "geometric"]),
    n=st.integers(8, 120),
    d=st.sampled_from([2, 3]),
    redundancy=st.sampled_from([0.0, 0.1, 0.5]),
    seed=st.integers(0, 10_000),
    p_loss=st.sampled_from([0.01, 0.05, 0.2]),
)
def test_every_family_and_mask_answers_as_the_svd(
    name: str, n: int, d: int, redundancy: float, seed: int, p_loss: float
) -> None:
    d = 2 if name == "henneberg" else d
    s = family(name, n, d, redundancy, seed)
    x, edges = s.offsets, s.edge_array
    rounds = growth_rounds(x, edges)
    need = expected_rigidity_rank(*x.shape)
    rng = np.random.default_rng(seed)
    for _ in range(4):
        mask = rng.random(len(edges)) >= p_loss
        svd = rigidity_rank(x, edges[mask])
        rank, rigid = rank_under_mask(x, edges, rounds, mask, spread=False, svd_max_columns=0)
        assert rigid == (svd == need)
        assert rank in (svd, None)
        cluster = grown_cluster(x, edges[mask])
        if cluster.sum() > d and not cluster.all():  # a body, agents outside it
            bodies = np.where(cluster, HELD, FREE)
            assert outside_held(x, edges[mask], bodies) == (svd == need)
            if unbraced_outside(outside_matrix(x, edges[mask], bodies)):
                assert svd < need


def lost_region(x: np.ndarray, edges: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The edges touching the agents near a random one: a burst that cuts growth off."""
    centre = x[rng.integers(len(x))]
    near = np.linalg.norm(x - centre, axis=1) < rng.uniform(1.0, 3.0)
    return near[edges[:, 0] - 1] | near[edges[:, 1] - 1]


@settings(max_examples=2, deadline=None)
@given(
    name=st.sampled_from(["henneberg", "rigid_team", "geometric"]),
    d=st.sampled_from([2, 3]),
    size=st.floats(0.4, 1.0),
    redundancy=st.sampled_from([0.1, 0.5]),
    seed=st.integers(0, 10_000),
    p_loss=st.sampled_from([0.01, 0.05, 0.3]),
    burst=st.booleans(),
)
@example(name="henneberg", d=2, size=1.0, redundancy=0.1, seed=1, p_loss=0.01, burst=True)
def test_up_to_a_thousand_agents_the_answer_is_the_dense_svds(
    name: str, d: int, size: float, redundancy: float, seed: int, p_loss: float, burst: bool
) -> None:
    """Teams of 400-1,000 agents in the plane, 200-500 in space (the SVD's cost: its columns)."""
    d = 2 if name == "henneberg" else d
    n = round(size * (1000 if d == 2 else 500))
    s = family(name, n, d, redundancy, seed)
    x, edges = s.offsets, s.edge_array
    rng = np.random.default_rng(seed)
    mask = rng.random(len(edges)) >= p_loss
    if burst:
        mask &= ~lost_region(x, edges, rng)
    svd = rigidity_rank(x, edges[mask])
    rank, rigid = rank_under_mask(x, edges, growth_rounds(x, edges), mask, spans_without_any(x))
    assert rigid == (svd == expected_rigidity_rank(n, d))
    assert rank in (svd, None)


def test_the_agents_outside_decide_where_the_whole_stiffness_did() -> None:
    s = henneberg_team(120, seed=7, redundancy=0.1)
    x, edges = s.offsets, s.edge_array
    rounds = growth_rounds(x, edges)
    rng = np.random.default_rng(7)
    decided = 0
    for _ in range(20):
        mask = rng.random(len(edges)) >= 0.02
        cluster = grown_cluster(x, edges[mask])
        if cluster.sum() <= 2 or cluster.all():
            continue
        if rank_beyond_cluster(x, edges[mask], cluster, 0) is None:  # past the SVDs
            decided += 1
            fast = rank_under_mask(x, edges, rounds, mask, False, svd_max_columns=0)
            whole = rank_under_mask(
                x, edges, rounds, mask, False, svd_max_columns=0, outside_stiffness=False
            )
            assert fast[1] == whole[1] == (rigidity_rank(x, edges[mask]) == 237)
    assert decided > 5


def test_full_column_rank_is_the_svds() -> None:
    x = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.2, 1.1], [2.0, 0.0]])
    held = sparse_rigidity_matrix(x, [[2, 4], [3, 4]])[:, 6:8]  # agent 4 by two directions
    assert full_column_rank(held)
    assert not full_column_rank(held[:1])  # fewer rows than columns
    line = sparse_rigidity_matrix(x, [[1, 2], [2, 5]])[:, 2:4]  # agent 2 between two on a line
    assert not full_column_rank(line)


@pytest.mark.parametrize("d", [2, 3])
def test_geometric_teams_are_rigid_and_spaced(d: int) -> None:
    s = geometric_team(300, d, 0.1, seed=5)
    x, edges = s.offsets, s.edge_array
    base = 300 * d - d * (d + 1) // 2
    assert len(edges) == base + round(0.1 * base)
    assert rigidity_rank(x, edges) == base
    gaps = np.linalg.norm(x[:, None] - x[None], axis=-1) + np.eye(300) * 1e9
    assert gaps.min() >= 0.3


def test_henneberg_spare_edges_are_new_and_short() -> None:
    plain = henneberg_team(200, seed=4)
    spare = henneberg_team(200, seed=4, redundancy=0.5)
    assert np.array_equal(plain.offsets, spare.offsets)
    base = {tuple(e) for e in plain.edge_array.tolist()}
    added = [tuple(e) for e in spare.edge_array.tolist()][len(base) :]
    assert len(added) == round(0.5 * (2 * 200 - 3))
    assert not base & set(added) and len(set(added)) == len(added)
    x = spare.offsets
    assert all(np.linalg.norm(x[a - 1] - x[b - 1]) <= 1.5 for a, b in added)


def cut_at_the_seed(x: np.ndarray, edges: np.ndarray, rounds: np.ndarray) -> np.ndarray:
    """A mask that leaves the agents next to the growth order's first simplex at most ``d − 1``
    edges into it: growth from the seed stalls at the simplex, the rest is another body."""
    d = x.shape[1]
    first = rounds <= np.sort(rounds)[d]  # the simplex's d + 1 agents
    into = first[edges[:, 0] - 1] != first[edges[:, 1] - 1]
    outer = np.where(first[edges[:, 0] - 1], edges[:, 1], edges[:, 0])
    mask = np.ones(len(edges), dtype=bool)
    for agent in np.unique(outer[into]):
        mine = np.flatnonzero(into & (outer == agent))
        mask[mine[d - 1 :]] = False
    return mask


@pytest.mark.parametrize(
    ("name", "d", "redundancy"),
    [("geometric", 3, 0.5), ("rigid_team", 2, 0.5), ("henneberg", 2, 0.5)],
)
def test_a_second_cluster_ranks_what_the_first_left_out(
    name: str, d: int, redundancy: float
) -> None:
    s = family(name, 150, d, redundancy, 3)
    x, edges = s.offsets, s.edge_array
    rounds = growth_rounds(x, edges)
    mask = cut_at_the_seed(x, edges, rounds)
    kept = edges[mask]
    cluster = grown_cluster(x, kept)
    assert cluster.sum() == d + 1  # stalled at the simplex
    bodies = further_bodies(x, kept, cluster, half_edges(x, kept - 1))
    assert np.bincount(bodies[bodies > HELD]).max() > 100  # a second body, most of the team
    svd = rigidity_rank(x, kept)
    assert rank_beyond_cluster(x, kept, cluster, 60) is None  # the agents outside: too many
    assert outside_rank(x, kept, bodies, 60) == svd  # as bodies: a few columns
    need = expected_rigidity_rank(*x.shape)
    assert rank_under_mask(x, edges, rounds, mask, False, svd_max_columns=60) == (svd, svd == need)
    assert outside_held(x, kept, bodies) == (svd == need)
    lost = mask.copy()
    lost[np.flatnonzero(mask)[-1]] = False  # one edge fewer
    svd = rigidity_rank(x, edges[lost])
    assert rank_under_mask(x, edges, rounds, lost, False, svd_max_columns=60)[0] in (svd, None)
