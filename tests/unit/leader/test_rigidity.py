"""Rigidity of frameworks and of the healthy subgraph (docs/model.md §2)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import formation.rigidity
import formation.rigidity_check
from leader.rigidity import expected_rank, healthy_rigidity, is_rigid, rigidity_rank

PROPERTY = settings(max_examples=40, deadline=None, derandomize=True, database=None)

SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
SQUARE_EDGES = [(1, 2), (2, 3), (3, 4), (4, 1)]
TETRAHEDRON = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
TETRA_EDGES = [(1, 2), (1, 3), (1, 4), (2, 3), (2, 4), (3, 4)]


def pentagon() -> tuple[np.ndarray, list[tuple[int, int]]]:
    """The default scenario's shape (docs/model.md §8)."""
    angles = np.deg2rad(90.0 + 72.0 * np.arange(5))
    x = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    return x, [(1, 2), (1, 3), (2, 3), (2, 4), (1, 4), (3, 5), (4, 5)]


def henneberg(n: int, d: int, rng: np.random.Generator) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """Minimally rigid by Henneberg type-I steps: a (d+1)-clique, then each new agent joins d old ones."""
    x = rng.standard_normal((n, d))
    base = min(n, d + 1)
    edges = [(i, j) for i in range(1, base + 1) for j in range(i + 1, base + 1)]
    for k in range(base + 1, n + 1):
        for j in rng.choice(np.arange(1, k), size=d, replace=False):
            edges.append((int(j), k))
    return x, edges


def test_reexports_are_the_formation_functions() -> None:
    assert rigidity_rank is formation.rigidity.rigidity_rank
    assert is_rigid is formation.rigidity_check.is_rigid
    assert expected_rank is formation.rigidity.expected_rigidity_rank


def test_triangle_is_rigid() -> None:
    x = np.array([[0.0, 0.0], [1.0, 0.0], [0.3, 0.8]])
    assert rigidity_rank(x, [(1, 2), (2, 3), (3, 1)]) == 3
    assert is_rigid(x, [(1, 2), (2, 3), (3, 1)])


def test_collinear_triangle_is_not_rigid() -> None:
    x = np.array([[0.0, 0.0], [1.0, 0.0], [2.5, 0.0]])
    assert rigidity_rank(x, [(1, 2), (2, 3), (3, 1)]) == 2
    assert not is_rigid(x, [(1, 2), (2, 3), (3, 1)])


def test_square_flexible_without_diagonal_rigid_with_one() -> None:
    assert rigidity_rank(SQUARE, SQUARE_EDGES) == 4
    assert not is_rigid(SQUARE, SQUARE_EDGES)
    assert rigidity_rank(SQUARE, [*SQUARE_EDGES, (1, 3)]) == 5
    assert is_rigid(SQUARE, [*SQUARE_EDGES, (1, 3)])


def test_default_pentagon_rigid_and_loses_rigidity_without_link_1_2() -> None:
    x, edges = pentagon()
    assert len(edges) == 2 * 5 - 3
    assert healthy_rigidity(x, edges, [True] * 7) == (7, True)
    assert healthy_rigidity(x, edges, [False] + [True] * 6) == (6, False)


@PROPERTY
@given(st.integers(0, 2**32 - 1), st.integers(2, 25), st.sampled_from([2, 3]))
def test_henneberg_construction_is_minimally_rigid(seed: int, n: int, d: int) -> None:
    rng = np.random.default_rng(seed)
    x, edges = henneberg(n, d, rng)
    assert len(edges) == expected_rank(n, d)
    assert is_rigid(x, edges)
    drop = int(rng.integers(len(edges)))
    mask = np.ones(len(edges), dtype=bool)
    mask[drop] = False
    rank, rigid = healthy_rigidity(x, edges, mask)
    assert (rank, rigid) == (expected_rank(n, d) - 1, False)


def test_tetrahedron_rigid_missing_edge_flexible() -> None:
    assert rigidity_rank(TETRAHEDRON, TETRA_EDGES) == 6
    assert is_rigid(TETRAHEDRON, TETRA_EDGES)
    assert not is_rigid(TETRAHEDRON, TETRA_EDGES[:-1])
    assert rigidity_rank(TETRAHEDRON, TETRA_EDGES[:-1]) == 5


def test_triangular_bipyramid_missing_edge_is_flexible_in_3d() -> None:
    x = np.array(
        [[1.0, 0.0, 0.0], [-0.5, 0.8, 0.1], [-0.4, -0.9, 0.0], [0.1, 0.0, 1.2], [0.0, 0.1, -1.1]]
    )
    edges = [(1, 2), (2, 3), (3, 1)] + [(a, 4) for a in (1, 2, 3)] + [(a, 5) for a in (1, 2, 3)]
    assert len(edges) == 3 * 5 - 6
    assert is_rigid(x, edges)
    assert not is_rigid(x, edges[1:])


def test_few_agents_in_3d() -> None:
    assert expected_rank(1, 3) == 0
    assert is_rigid(np.zeros((1, 3)), [])
    two = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]])
    assert rigidity_rank(two, [(1, 2)]) == 1 == expected_rank(2, 3)
    assert is_rigid(two, [(1, 2)])
    assert not is_rigid(two, [])
    three = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.5]])
    assert is_rigid(three, [(1, 2), (2, 3), (1, 3)])  # 3 = 3n − 6 = n(n−1)/2 at n = 3
    assert not is_rigid(three, [(1, 2), (2, 3)])


@pytest.mark.parametrize(
    ("n", "d", "rank"),
    [(1, 2, 0), (2, 2, 1), (10, 2, 17), (1, 3, 0), (2, 3, 1), (3, 3, 3), (10, 3, 24)],
)
def test_expected_rank(n: int, d: int, rank: int) -> None:
    assert expected_rank(n, d) == rank


def test_healthy_mask_shape_is_checked() -> None:
    x, edges = pentagon()
    with pytest.raises(ValueError, match=r"^healthy_mask has shape \(3,\); expected \(7,\)$"):
        healthy_rigidity(x, edges, [True, True, True])


def test_tracker_equals_the_svd_on_random_masks() -> None:
    from pathlib import Path

    from formation.scenario import Scenario
    from leader.rigidity import HealthyRigidity, healthy_rigidity

    paper = Scenario.from_file(Path(__file__).resolve().parents[3] / "scenarios/paper.toml")
    rng = np.random.default_rng(11)
    extra = np.vstack([paper.edge_array, [[2, 5], [3, 4]]])  # over-constrained: rows dependent
    for edges in (paper.edge_array, extra):
        tracker = HealthyRigidity(paper.offsets, edges)
        assert tracker.independent == (len(edges) == 7)
        for _ in range(60):
            mask = rng.random(len(edges)) < 0.7
            assert tracker(mask) == healthy_rigidity(paper.offsets, edges, mask)
