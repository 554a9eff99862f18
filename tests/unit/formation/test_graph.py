"""Edge checks, connectivity, degree and the rigidity matrix of formation.graph (docs/model.md §1, §2)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from formation.errors import AgentIdError, GraphInputError, ShapeError, TestbedError
from formation.graph import as_edge_array, component_labels, is_connected, max_degree
from formation.rigidity import expected_rigidity_rank, rigidity_matrix, rigidity_rank
from formation.rigidity_check import is_rigid

PROPERTY = settings(max_examples=60, deadline=None, derandomize=True, database=None)


@pytest.fixture
def rng(seed: int) -> np.random.Generator:
    """Generator from the suite's ``seed`` fixture (tests/conftest.py)."""
    return np.random.default_rng(seed)


# --------------------------------------------------------------------------- edge checks


def test_edge_array_accepts_lists_and_empty() -> None:
    assert as_edge_array(3, [(1, 2), (3, 2)]).tolist() == [[1, 2], [3, 2]]
    assert as_edge_array(3, []).shape == (0, 2)


def test_edge_array_wrong_shape_says_expected() -> None:
    with pytest.raises(ShapeError, match=r"^edges has shape \(2, 3\); expected \(m, 2\)$"):
        as_edge_array(3, [(1, 2, 3), (1, 2, 3)])


def test_edge_array_id_out_of_range_names_edge_and_agent() -> None:
    with pytest.raises(
        AgentIdError, match=r"^edges\[1\] = \(2, 9\) names agent 9; expected ids in 1\.\.5$"
    ):
        as_edge_array(5, [(1, 2), (2, 9)])
    with pytest.raises(AgentIdError, match=r"names agent 0; expected ids in 1\.\.5$"):
        as_edge_array(5, [(0, 2)])


def test_edge_array_rejects_self_loops_and_floats() -> None:
    with pytest.raises(AgentIdError, match=r"^edges\[0\] = \(2, 2\) is a self-loop; expected two"):
        as_edge_array(3, [(2, 2)])
    with pytest.raises(
        GraphInputError, match=r"^edges has dtype float64; expected integer agent ids$"
    ):
        as_edge_array(3, [(1.0, 2.0)])


def test_input_errors_are_value_errors_and_testbed_errors() -> None:
    with pytest.raises(ValueError) as info:
        as_edge_array(2, [(1, 3)])
    assert isinstance(info.value, TestbedError)


# --------------------------------------------------------------------------- connectivity, degree


def test_component_labels_numbered_by_smallest_agent() -> None:
    # components {1, 4}, {2, 5}, {3}
    labels = component_labels(5, [(5, 2), (4, 1)])
    assert labels.tolist() == [0, 1, 2, 0, 1]


def test_component_labels_respects_mask() -> None:
    edges = [(1, 2), (2, 3)]
    assert component_labels(3, edges, [True, False]).tolist() == [0, 0, 1]
    assert component_labels(3, edges).tolist() == [0, 0, 0]


def test_is_connected() -> None:
    assert is_connected(1, [])
    assert is_connected(3, [(1, 2), (3, 2)])
    assert not is_connected(3, [(1, 2)])
    assert not is_connected(4, [(1, 2), (3, 4)])


def test_max_degree_counts_distinct_neighbours() -> None:
    assert max_degree(4, []) == 0
    assert max_degree(4, [(1, 2), (1, 3), (1, 4), (2, 3)]) == 3
    assert max_degree(3, [(1, 2), (2, 1), (1, 2)]) == 1  # parallel edges: one neighbour
    pentagon = [(1, 2), (1, 3), (2, 3), (2, 4), (1, 4), (3, 5), (4, 5)]
    assert max_degree(5, pentagon) == 3  # docs/model.md §8: Δ_max = 3


# --------------------------------------------------------------------------- rigidity matrix


def test_rigidity_matrix_rows() -> None:
    x = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 2.0]])
    r = rigidity_matrix(x, [(1, 2), (3, 1)])
    expected = np.array(
        [
            [-1.0, 0.0, 1.0, 0.0, 0.0, 0.0],  # x1 − x2 in block 1, x2 − x1 in block 2
            [0.0, -2.0, 0.0, 0.0, 0.0, 2.0],  # edge (3, 1): x3 − x1 in block 3
        ]
    )
    np.testing.assert_array_equal(r, expected)


@PROPERTY
@given(st.integers(0, 2**32 - 1), st.integers(2, 7), st.sampled_from([2, 3]))
def test_rigidity_matrix_is_half_the_derivative_of_squared_lengths(
    seed: int, n: int, d: int
) -> None:
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((n, d))
    edges = np.array([(i, j) for i in range(1, n + 1) for j in range(i + 1, n + 1)])
    v = rng.standard_normal((n, d))
    h = 1e-6

    def lengths2(q: np.ndarray) -> np.ndarray:
        diff = q[edges[:, 0] - 1] - q[edges[:, 1] - 1]
        return np.asarray((diff**2).sum(axis=1))

    numeric = (lengths2(x + h * v) - lengths2(x - h * v)) / (2 * h)
    np.testing.assert_allclose(rigidity_matrix(x, edges) @ v.ravel(), numeric / 2, atol=1e-6)


@pytest.mark.parametrize(
    ("n", "d", "rank"),
    [
        (1, 2, 0),
        (2, 2, 1),
        (3, 2, 3),
        (5, 2, 7),
        (1, 3, 0),
        (2, 3, 1),
        (3, 3, 3),
        (4, 3, 6),
        (5, 3, 9),
    ],
)
def test_expected_rigidity_rank(n: int, d: int, rank: int) -> None:
    assert expected_rigidity_rank(n, d) == rank


@PROPERTY
@given(st.integers(0, 2**32 - 1), st.integers(1, 8), st.sampled_from([2, 3]))
def test_complete_generic_framework_has_expected_rank_under_rigid_motion(
    seed: int, n: int, d: int
) -> None:
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((n, d))
    edges = [(i, j) for i in range(1, n + 1) for j in range(i + 1, n + 1)]
    q, _ = np.linalg.qr(rng.standard_normal((d, d)))
    moved = x @ q.T + rng.standard_normal(d)
    assert rigidity_rank(x, edges) == expected_rigidity_rank(n, d)
    assert rigidity_rank(moved, edges) == rigidity_rank(x, edges)
    assert is_rigid(moved, edges)


def test_rank_of_coincident_points_is_zero() -> None:
    assert rigidity_rank(np.zeros((3, 2)), [(1, 2), (2, 3)]) == 0
    assert rigidity_rank(np.zeros((3, 2)), []) == 0


def test_positions_must_be_finite_2d() -> None:
    with pytest.raises(ShapeError, match=r"^positions has shape \(3,\); expected \(n, d\)"):
        rigidity_rank(np.zeros(3), [])
    with pytest.raises(GraphInputError, match=r"^positions\[1\] is not finite; expected finite"):
        rigidity_rank([[0.0, 0.0], [np.nan, 1.0]], [(1, 2)])
