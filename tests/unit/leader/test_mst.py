"""Kruskal's minimum spanning forest over healthy edges (docs/model.md §4)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse import coo_array
from scipy.sparse.csgraph import connected_components, minimum_spanning_tree

import leader.mst
from formation.errors import AgentIdError, ShapeError
from formation.scenario import Scenario
from leader.mst import KruskalGraph, components, minimum_spanning_forest

SCENARIOS = Path(__file__).resolve().parents[3] / "scenarios"
PROPERTY = settings(max_examples=300, deadline=None, derandomize=True, database=None)


@pytest.fixture
def rng(seed: int) -> np.random.Generator:
    """Generator from the suite's ``seed`` fixture (tests/conftest.py)."""
    return np.random.default_rng(seed)


def random_graph(
    rng: np.random.Generator, n: int, m: int, ties: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Up to ``m`` distinct undirected pairs, randomly oriented, 1-based; weights and a mask."""
    if n < 2:
        return np.empty((0, 2), dtype=np.int64), np.empty(0), np.empty(0, dtype=bool)
    a, b = rng.integers(1, n + 1, 3 * m + 3), rng.integers(1, n + 1, 3 * m + 3)
    ok = a != b
    pairs = np.unique(np.sort(np.stack([a[ok], b[ok]], 1), 1), axis=0)
    pairs = pairs[rng.permutation(len(pairs))[:m]]
    flip = rng.random(len(pairs)) < 0.5
    edges = np.where(flip[:, None], pairs[:, ::-1], pairs)
    # positive weights: scipy reads a zero entry as "no edge"
    weights = rng.integers(1, 4, len(edges)).astype(float) if ties else rng.random(len(edges)) + 0.1
    healthy = rng.random(len(edges)) < rng.uniform(0.3, 1.0)
    return edges, weights, healthy


def scipy_forest_weight(n: int, edges: np.ndarray, weights: np.ndarray, mask: np.ndarray) -> float:
    e = edges[mask] - 1
    g = coo_array((weights[mask], (e[:, 0], e[:, 1])), shape=(n, n))
    return float(minimum_spanning_tree(g).sum())


def scipy_components(n: int, edges: np.ndarray, mask: np.ndarray) -> int:
    e = edges[mask] - 1
    g = coo_array((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    return int(connected_components(g, directed=False)[0])


def plain_kruskal(n: int, edges: np.ndarray, weights: np.ndarray, mask: np.ndarray) -> list[int]:
    """Independent textbook Kruskal: sorted() on the tie-break key, a dict union-find."""
    key = lambda k: (weights[k], min(edges[k]), max(edges[k]), k)  # noqa: E731
    parent = {i: i for i in range(1, n + 1)}

    def find(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    kept = []
    for k in sorted(np.flatnonzero(mask).tolist(), key=key):
        a, b = find(int(edges[k][0])), find(int(edges[k][1]))
        if a != b:
            parent[a] = b
            kept.append(k)
    return kept


def is_forest(n: int, edges: np.ndarray, chosen: list[int]) -> bool:
    parent = list(range(n + 1))

    def find(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    for k in chosen:
        a, b = find(int(edges[k][0])), find(int(edges[k][1]))
        if a == b:
            return False
        parent[a] = b
    return True


@PROPERTY
@given(st.integers(0, 2**32 - 1), st.integers(1, 60), st.floats(0.0, 6.0), st.booleans())
def test_total_weight_matches_scipy_and_forest_spans_components(
    seed: int, n: int, density: float, ties: bool
) -> None:
    rng = np.random.default_rng(seed)
    edges, weights, healthy = random_graph(rng, n, int(density * n), ties)
    chosen = minimum_spanning_forest(n, edges, weights, healthy)
    assert all(healthy[k] for k in chosen)
    assert is_forest(n, edges, chosen)
    assert len(chosen) == n - scipy_components(n, edges, healthy)
    np.testing.assert_allclose(
        weights[chosen].sum(), scipy_forest_weight(n, edges, weights, healthy), rtol=1e-12
    )
    assert chosen == plain_kruskal(n, edges, weights, healthy)


@PROPERTY
@given(st.integers(0, 2**32 - 1), st.integers(2, 40))
def test_same_forest_under_edge_permutation_and_orientation_with_ties(seed: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    edges, weights, healthy = random_graph(rng, n, 3 * n, ties=True)
    base = minimum_spanning_forest(n, edges, weights, healthy)
    perm = rng.permutation(len(edges))
    flip = rng.random(len(edges)) < 0.5
    shuffled = np.where(flip[:, None], edges[:, ::-1], edges)[perm]
    again = minimum_spanning_forest(n, shuffled, weights[perm], healthy[perm])

    def pairs(e: np.ndarray, idx: list[int]) -> list[tuple[int, int]]:
        return sorted((int(min(e[k])), int(max(e[k]))) for k in idx)

    assert pairs(shuffled, again) == pairs(edges, base)


def test_equal_weights_break_ties_by_smallest_ids() -> None:
    # square 1-2-3-4 with equal weights: order (1,2) (1,4) (2,3) (3,4); the last closes a cycle
    edges = [(3, 4), (2, 3), (4, 1), (2, 1)]
    chosen = minimum_spanning_forest(4, edges, [1.0] * 4, [True] * 4)
    assert chosen == [3, 2, 1]


def test_lighter_edge_wins_and_unhealthy_edges_are_skipped() -> None:
    edges = [(1, 2), (2, 3), (1, 3)]
    assert minimum_spanning_forest(3, edges, [1.0, 2.0, 3.0], [True, True, True]) == [0, 1]
    assert minimum_spanning_forest(3, edges, [1.0, 2.0, 3.0], [False, True, True]) == [1, 2]


def test_disconnected_mask_gives_forest_with_n_minus_c_edges() -> None:
    edges = [(1, 2), (2, 3), (4, 5), (5, 6), (3, 4)]
    chosen = minimum_spanning_forest(7, edges, [1.0] * 5, [True, True, True, True, False])
    assert sorted(chosen) == [0, 1, 2, 3]  # components {1,2,3}, {4,5,6}, {7}: 7 − 3 edges
    assert components(7, edges, [True, True, True, True, False]).tolist() == [0, 0, 0, 1, 1, 1, 2]


def test_trivial_inputs() -> None:
    assert minimum_spanning_forest(1, [], [], []) == []
    assert minimum_spanning_forest(3, [(1, 2)], [1.0], [False]) == []


def test_large_graph_matches_plain_kruskal(rng: np.random.Generator) -> None:
    # many more edges than agents: exercises the bulk rejection between chunks
    n = 400
    edges, weights, healthy = random_graph(rng, n, 6000, ties=False)
    healthy[:] = True
    chosen = minimum_spanning_forest(n, edges, weights, healthy)
    assert chosen == plain_kruskal(n, edges, weights, healthy)
    assert len(chosen) == n - scipy_components(n, edges, healthy)


def test_bad_inputs_say_expected_vs_actual() -> None:
    edges = [(1, 2), (2, 3)]
    with pytest.raises(ShapeError, match=r"^weights has shape \(3,\); expected \(2,\)$"):
        minimum_spanning_forest(3, edges, [1.0, 2.0, 3.0], [True, True])
    with pytest.raises(ShapeError, match=r"^healthy has shape \(1,\); expected \(2,\)$"):
        minimum_spanning_forest(3, edges, [1.0, 2.0], [True])
    with pytest.raises(
        AgentIdError, match=r"^edges\[1\] = \(2, 4\) names agent 4; expected ids in 1\.\.3$"
    ):
        minimum_spanning_forest(3, [(1, 2), (2, 4)], [1.0, 2.0], [True, True])
    with pytest.raises(ValueError, match=r"^weights\[0\] = nan; expected a finite weight$"):
        minimum_spanning_forest(3, edges, [np.nan, 2.0], [True, True])
    with pytest.raises(ValueError, match=r"^healthy has dtype float64; expected booleans"):
        minimum_spanning_forest(3, edges, [1.0, 2.0], [0.5, 1.0])


@pytest.mark.parametrize(
    ("sweep_ratio", "union_find_from", "in_python_upto"),
    [(0, 10**9, 0), (10**9, 10**9, 0), (0, 0, 0), (10**9, 10**9, 10**9)],
    ids=["label sweep", "scipy", "union-find", "python"],
)
def test_batch_forest_is_kruskals(
    paper: Scenario,
    sweep_ratio: int,
    union_find_from: int,
    in_python_upto: int,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The four scans of :meth:`KruskalGraph.forests` (forced by ``LABEL_SWEEP_RATIO``,
    ``UNION_FIND_FROM`` and ``SCAN_IN_PYTHON_UPTO``) keep each member's Kruskal forest."""
    monkeypatch.setattr(leader.mst, "LABEL_SWEEP_RATIO", sweep_ratio)
    monkeypatch.setattr(leader.mst, "UNION_FIND_FROM", union_find_from)
    monkeypatch.setattr(leader.mst, "SCAN_IN_PYTHON_UPTO", in_python_upto)
    team = Scenario.from_file(SCENARIOS / "grid20.toml")
    rng = np.random.default_rng(5)
    for scen in (paper, team):
        healthy = rng.random((40, len(scen.edge_array))) < 0.6
        tree, labels = KruskalGraph.of(scen.n, scen.edge_array, scen.weights).forests(healthy)
        for b in range(healthy.shape[0]):
            want = np.zeros(len(scen.edge_array), dtype=bool)
            want[minimum_spanning_forest(scen.n, scen.edge_array, scen.weights, healthy[b])] = True
            np.testing.assert_array_equal(tree[b], want)
            assert len(np.unique(labels[b])) == scen.n - want.sum()


@pytest.mark.parametrize(
    ("union_find_from", "in_python_upto"),
    [(10**9, 0), (0, 0), (10**9, 10**9)],
    ids=["scipy", "union-find", "python"],
)
def test_batch_forest_of_an_edge_listed_twice_keeps_the_first_copy(
    union_find_from: int, in_python_upto: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(leader.mst, "UNION_FIND_FROM", union_find_from)
    monkeypatch.setattr(leader.mst, "SCAN_IN_PYTHON_UPTO", in_python_upto)
    edges = np.array([(1, 2), (2, 3), (1, 2), (1, 3)])
    weights = np.array([2.0, 1.0, 0.5, 3.0])
    healthy = np.array([[True, True, True, True], [True, True, False, True]])
    tree, labels = KruskalGraph.of(3, edges, weights).forests(healthy)
    for b in range(2):
        want = np.zeros(4, dtype=bool)
        want[minimum_spanning_forest(3, edges, weights, healthy[b])] = True
        np.testing.assert_array_equal(tree[b], want)
    assert tree.tolist() == [[False, True, True, False], [True, True, False, False]]
    assert len(np.unique(labels)) == 2


def test_the_union_find_gives_scipys_forest_and_labels(rng: np.random.Generator) -> None:
    """On a large team the compiled union-find and SciPy's scan agree array for array, the
    component labels too (numbered by each component's smallest agent)."""
    n, m = 3000, 7000
    edges = np.stack([rng.integers(1, n + 1, m), rng.integers(1, n + 1, m)], axis=1)
    edges = edges[edges[:, 0] != edges[:, 1]]
    graph = KruskalGraph.of(n, edges, rng.random(edges.shape[0]))
    healthy = rng.random((3, edges.shape[0])) < 0.7
    want = leader.mst._sparse_scan(n, graph.lo, graph.hi, graph.order, healthy)
    got = graph.forests(healthy)  # 9,000 nodes: the union-find
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])


def test_a_small_batch_is_scanned_in_python_with_scipys_forest_and_labels(
    rng: np.random.Generator,
) -> None:
    """A batch of a few hundred edges takes the Python scan, which keeps SciPy's forest and
    gives its component labels array for array, members apart and edges listed twice too."""
    n, m, members = 30, 70, 6
    edges = np.stack([rng.integers(1, n + 1, m), rng.integers(1, n + 1, m)], axis=1)
    edges = edges[edges[:, 0] != edges[:, 1]]
    edges = np.concatenate([edges, edges[:5]])  # listed twice
    graph = KruskalGraph.of(n, edges, rng.random(edges.shape[0]))
    healthy = rng.random((members, edges.shape[0])) < 0.6
    assert members * edges.shape[0] <= leader.mst.SCAN_IN_PYTHON_UPTO
    assert edges.shape[0] * leader.mst.LABEL_SWEEP_RATIO >= members * n  # not the sweep's
    want = leader.mst._sparse_scan(n, graph.lo, graph.hi, graph.order, healthy)
    got = graph.forests(healthy)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
