"""BLUE of positions relative to the reference (docs/model.md §5), against independent dense solutions."""

from __future__ import annotations

from typing import Literal

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import leader.laplacian as laplacian_module
from analysis import nees
from formation.errors import AgentIdError, CovarianceError, GraphInputError, ShapeError
from leader.estimation import BlueResult, blue
from leader.mst import minimum_spanning_forest
from testkit.dense_oracle import dense_system

PROPERTY = settings(max_examples=40, deadline=None, derandomize=True, database=None)
CovKind = Literal["scalar", "diagonal", "full"]


@pytest.fixture
def rng(seed: int) -> np.random.Generator:
    """Generator from the suite's ``seed`` fixture (tests/conftest.py)."""
    return np.random.default_rng(seed)


# --------------------------------------------------------------------------- fixtures of the math


def connected_graph(rng: np.random.Generator, n: int, extra: int) -> np.ndarray:
    """A random spanning tree plus ``extra`` random edges (parallel ones allowed), random orientation."""
    tree = [(k, int(rng.integers(1, k))) for k in range(2, n + 1)]
    more: list[tuple[int, int]] = []
    while len(more) < extra and n > 1:
        a, b = (int(v) for v in rng.integers(1, n + 1, 2))
        if a != b:
            more.append((a, b))
    edges = np.array(tree + more, dtype=np.int64).reshape(-1, 2)
    flip = rng.random(len(edges)) < 0.5
    return np.where(flip[:, None], edges[:, ::-1], edges)


def covariances(rng: np.random.Generator, m: int, d: int, kind: CovKind) -> np.ndarray:
    if kind == "scalar":
        return rng.uniform(1e-4, 1.0, m)[:, None, None] * np.eye(d)
    if kind == "diagonal":
        return rng.uniform(1e-4, 1.0, (m, d))[:, :, None] * np.eye(d)
    a = rng.standard_normal((m, d, d)) * rng.uniform(0.01, 1.0, (m, 1, 1))
    return a @ a.transpose(0, 2, 1) + 1e-3 * np.eye(d)


def measure(
    rng: np.random.Generator, x: np.ndarray, edges: np.ndarray, cov: np.ndarray
) -> np.ndarray:
    """``z_e = x_i − x_j + ε_e`` with ``ε_e ~ N(0, P_e)``."""
    noise = np.einsum(
        "eab,eb->ea", np.linalg.cholesky(cov), rng.standard_normal((len(edges), x.shape[1]))
    )
    return np.asarray(x[edges[:, 0] - 1] - x[edges[:, 1] - 1] + noise)


def path_sum(
    n: int,
    edges: np.ndarray,
    z: np.ndarray,
    cov: np.ndarray,
    ref: int,
    x_ref: np.ndarray,
    use: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Walk a tree from the reference summing signed measurements and covariances (no solver)."""
    d = z.shape[1]
    adj: dict[int, list[tuple[int, int, float]]] = {a: [] for a in range(1, n + 1)}
    for e in np.flatnonzero(use):
        i, j = (int(v) for v in edges[e])
        adj[i].append((j, int(e), -1.0))  # x_j = x_i − z_e
        adj[j].append((i, int(e), 1.0))  # x_i = x_j + z_e
    x = np.full((n, d), np.nan)
    c = np.full((n, d, d), np.nan)
    x[ref - 1], c[ref - 1] = x_ref, 0.0
    stack: list[int] = [ref]
    while stack:
        a = stack.pop()
        for b, k, sign in adj[a]:
            if np.isnan(x[b - 1, 0]):
                x[b - 1] = x[a - 1] + sign * z[k]
                c[b - 1] = c[a - 1] + cov[k]
                stack.append(b)
    return x, c


def assert_matches(result: BlueResult, x: np.ndarray, c: np.ndarray, tol: float = 1e-9) -> None:
    assert result.covariances is not None
    np.testing.assert_allclose(result.positions, x, rtol=0, atol=tol * max(1.0, np.abs(x).max()))
    np.testing.assert_allclose(result.covariances, c, rtol=0, atol=tol * max(1e-3, np.abs(c).max()))


# --------------------------------------------------------------------------- against dense solutions


@PROPERTY
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(2, 200),
    d=st.sampled_from([2, 3]),
    kind=st.sampled_from(["scalar", "diagonal", "full"]),
    edge_set=st.sampled_from(["all", "tree"]),
    cycles=st.floats(0.0, 1.5),
)
def test_equals_the_dense_normal_equations(
    seed: int, n: int, d: int, kind: CovKind, edge_set: str, cycles: float
) -> None:
    rng = np.random.default_rng(seed)
    x = 5.0 * rng.standard_normal((n, d))
    edges = connected_graph(rng, n, int(cycles * n))
    cov = covariances(rng, len(edges), d, kind)
    z = measure(rng, x, edges, cov)
    ref = int(rng.integers(1, n + 1))
    use = np.ones(len(edges), dtype=bool)
    if edge_set == "tree":
        use[:] = False
        use[
            minimum_spanning_forest(n, edges, rng.random(len(edges)), np.ones(len(edges), bool))
        ] = True
    result = blue(n, d, edges, z, cov, ref, x[ref - 1], use)
    assert result.observable.all()
    distinct = {(min(a, b), max(a, b)) for a, b in edges[use].tolist()}
    assert result.solver == ("tree" if len(distinct) == n - 1 else "direct")
    assert_matches(result, *dense_system(n, edges, z, cov, ref, x[ref - 1], use).solve())


@PROPERTY
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(2, 60),
    d=st.sampled_from([2, 3]),
    kind=st.sampled_from(["scalar", "diagonal", "full"]),
)
def test_on_a_tree_equals_path_summing_from_the_reference(
    seed: int, n: int, d: int, kind: CovKind
) -> None:
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((n, d))
    edges = connected_graph(rng, n, n)
    cov = covariances(rng, len(edges), d, kind)
    z = measure(rng, x, edges, cov)
    use = np.zeros(len(edges), dtype=bool)
    use[minimum_spanning_forest(n, edges, rng.random(len(edges)), np.ones(len(edges), bool))] = True
    ref = int(rng.integers(1, n + 1))
    result = blue(n, d, edges, z, cov, ref, x[ref - 1], use)
    assert result.solver == "tree"
    assert_matches(result, *path_sum(n, edges, z, cov, ref, x[ref - 1], use), tol=1e-12)


@pytest.mark.parametrize("kind", ["scalar", "diagonal", "full"])
@pytest.mark.parametrize("method", ["direct", "cg"])
def test_forced_cyclic_solvers_equal_dense(
    rng: np.random.Generator, kind: CovKind, method: str
) -> None:
    n, d = 120, 3
    x = rng.standard_normal((n, d))
    edges = connected_graph(rng, n, n)
    cov = covariances(rng, len(edges), d, kind)
    z = measure(rng, x, edges, cov)
    use = np.ones(len(edges), dtype=bool)
    result = blue(n, d, edges, z, cov, 1, x[0], use, solver=method)  # type: ignore[arg-type]
    assert result.solver == method
    # CG stops at a relative residual of 1e-12; its error is at most κ(A) times that
    tol = 1e-9 if method == "direct" else 1e-7
    assert_matches(result, *dense_system(n, edges, z, cov, 1, x[0], use).solve(), tol=tol)


def test_chunked_covariance_blocks_and_structure_choice(
    rng: np.random.Generator, monkeypatch: pytest.MonkeyPatch
) -> None:
    # shrink the thresholds so a small problem takes the large-n code paths
    monkeypatch.setattr(laplacian_module, "DIRECT_MAX_UNKNOWNS", 10)
    monkeypatch.setattr(laplacian_module, "INVERSE_CHUNK_COLUMNS", 7)
    n, d = 80, 3
    x = rng.standard_normal((n, d))
    edges = connected_graph(rng, n, n // 2)
    kinds: tuple[CovKind, ...] = ("scalar", "full")
    for kind in kinds:
        cov = covariances(rng, len(edges), d, kind)
        z = measure(rng, x, edges, cov)
        use = np.ones(len(edges), dtype=bool)
        result = blue(n, d, edges, z, cov, 5, x[4], use)
        assert result.solver in ("direct", "cg")
        assert_matches(result, *dense_system(n, edges, z, cov, 5, x[4], use).solve(), tol=1e-7)


def grid(side: int) -> np.ndarray:
    ids = np.arange(1, side * side + 1).reshape(side, side)
    return np.concatenate(
        [
            np.stack([ids[:, :-1].ravel(), ids[:, 1:].ravel()], 1),
            np.stack([ids[:-1].ravel(), ids[1:].ravel()], 1),
        ]
    )


def test_auto_factorises_a_planar_grid_and_iterates_on_an_expander(
    rng: np.random.Generator,
) -> None:
    n, d = 2500, 2

    def cov_of(m: int) -> np.ndarray:
        return np.broadcast_to(1e-4 * np.eye(d), (m, d, d))

    planar = grid(50)
    z = rng.standard_normal((len(planar), d))
    result = blue(n, d, planar, z, cov_of(len(planar)), 1, np.zeros(d), covariances=False)
    assert result.solver == "direct"
    assert result.covariances is None
    a, b = rng.integers(1, n + 1, 3 * n), rng.integers(1, n + 1, 3 * n)
    random_edges = np.concatenate(
        [connected_graph(rng, n, 0), np.stack([a, b], 1)[a != b][: 2 * n]]
    )
    z = rng.standard_normal((len(random_edges), d))
    cov = cov_of(len(random_edges))
    iterative = blue(n, d, random_edges, z, cov, 1, np.zeros(d), covariances=False)
    assert iterative.solver == "cg"
    direct = blue(n, d, random_edges, z, cov, 1, np.zeros(d), covariances=False, solver="direct")
    np.testing.assert_allclose(iterative.positions, direct.positions, rtol=0, atol=1e-9)


def test_parallel_measurements_of_one_link_are_both_used(rng: np.random.Generator) -> None:
    # both directions of every link reported: fused pairwise, still solved as a tree
    n, d = 6, 2
    x = rng.standard_normal((n, d))
    tree = connected_graph(rng, n, 0)
    edges = np.concatenate([tree, tree[:, ::-1]])
    cov = covariances(rng, len(edges), d, "full")
    z = measure(rng, x, edges, cov)
    use = np.ones(len(edges), dtype=bool)
    result = blue(n, d, edges, z, cov, 2, x[1], use)
    assert result.solver == "tree"
    assert_matches(result, *dense_system(n, edges, z, cov, 2, x[1], use).solve())
    cyclic = blue(n, d, edges, z, cov, 2, x[1], use, solver="direct")
    assert_matches(cyclic, *dense_system(n, edges, z, cov, 2, x[1], use).solve())


# --------------------------------------------------------------------------- observability


def test_unobservable_agents_are_nan_and_the_rest_still_right(rng: np.random.Generator) -> None:
    n, d = 9, 2
    x = rng.standard_normal((n, d))
    # agents 1..5 with a cycle, agents 6..8 on their own, agent 9 isolated; edge 4 unused
    edges = np.array([(1, 2), (2, 3), (3, 1), (3, 4), (5, 4), (4, 6), (6, 7), (8, 7), (7, 6)])
    use = np.array([1, 1, 1, 1, 1, 0, 1, 1, 1], dtype=bool)
    cov = covariances(rng, len(edges), d, "full")
    z = measure(rng, x, edges, cov)
    result = blue(n, d, edges, z, cov, 2, x[1], use)
    assert result.observable.tolist() == [True] * 5 + [False] * 4
    assert result.covariances is not None
    assert np.isnan(result.positions[5:]).all() and np.isnan(result.covariances[5:]).all()
    sub_x, sub_c = dense_system(5, edges[:5], z[:5], cov[:5], 2, x[1], use[:5]).solve()
    np.testing.assert_allclose(result.positions[:5], sub_x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(result.covariances[:5], sub_c, rtol=0, atol=1e-12)


def test_tree_component_with_unobservable_rest() -> None:
    edges = np.array([(1, 2), (3, 4)])
    z = np.array([[1.0, 2.0], [5.0, 5.0]])
    cov = np.broadcast_to(np.eye(2), (2, 2, 2))
    result = blue(4, 2, edges, z, cov, 2, np.array([10.0, 10.0]))
    assert result.solver == "tree"
    np.testing.assert_array_equal(result.positions[:2], [[11.0, 12.0], [10.0, 10.0]])
    assert result.observable.tolist() == [True, True, False, False]


def test_reference_alone() -> None:
    result = blue(3, 2, [(2, 3)], [[1.0, 1.0]], [np.eye(2)], 1, [4.0, 5.0])
    assert result.solver == "none"
    assert result.observable.tolist() == [True, False, False]
    np.testing.assert_array_equal(result.positions[0], [4.0, 5.0])
    assert result.covariances is not None
    np.testing.assert_array_equal(result.covariances[0], np.zeros((2, 2)))
    assert blue(1, 3, [], np.zeros((0, 3)), np.zeros((0, 3, 3)), 1, np.ones(3)).observable.all()


# --------------------------------------------------------------------------- Monte-Carlo honesty


def nees_per_agent(result: BlueResult, x_true: np.ndarray) -> np.ndarray:
    """The recorder's NEES (``analysis.nees``) of each agent of ``result``, NaN for the
    unobservable and the reference (its covariance is zero: nothing to normalise)."""
    assert result.covariances is not None
    scored = result.observable & (np.abs(result.covariances).sum(axis=(1, 2)) > 0)
    out = np.full(len(scored), np.nan)
    out[scored] = nees(result.positions, result.covariances, x_true, scored)
    return out


@pytest.mark.parametrize(("d", "kind", "edge_set"), [(2, "full", "all"), (3, "scalar", "tree")])
def test_covariance_and_nees_match_monte_carlo(
    seed: int, d: int, kind: CovKind, edge_set: str
) -> None:
    """2000 noise draws on a fixed graph (the suite's seed).

    Tolerances are 5 standard deviations: for the whitened empirical covariance
    ``C^{-1/2} Ĉ C^{-1/2}`` entries deviate from ``I`` by ``≈ sqrt(2 / N)``; the
    mean NEES of N χ²_d draws by ``sqrt(2 d / N)``; the mean whitened error by ``1/sqrt(N)``.
    """
    rng = np.random.default_rng(seed)
    n, trials = 20, 2000
    x = rng.standard_normal((n, d))
    edges = connected_graph(rng, n, n)
    cov = covariances(rng, len(edges), d, kind)
    use = np.ones(len(edges), dtype=bool)
    if edge_set == "tree":
        use[:] = False
        use[
            minimum_spanning_forest(n, edges, rng.random(len(edges)), np.ones(len(edges), bool))
        ] = True
    errors = np.empty((trials, n, d))
    scores = np.empty((trials, n))
    predicted = None
    for t in range(trials):
        result = blue(n, d, edges, measure(rng, x, edges, cov), cov, 1, x[0], use)
        errors[t] = result.positions - x
        scores[t] = nees_per_agent(result, x)
        predicted = result.covariances
    assert predicted is not None
    tol = 5 * np.sqrt(2 / trials)
    for agent in range(1, n):
        root = np.linalg.cholesky(predicted[agent])
        white = np.linalg.solve(root, errors[:, agent].T).T  # ~ N(0, I) if honest
        assert np.abs(white.mean(axis=0)).max() < 5 / np.sqrt(trials)
        np.testing.assert_allclose(np.cov(white.T), np.eye(d), atol=tol)
    assert np.isnan(scores[:, 0]).all()  # the reference has no error to normalise
    assert abs(scores[:, 1:].mean() - d) < 5 * np.sqrt(2 * d / trials)


def test_nees_value() -> None:
    result = BlueResult(
        positions=np.array([[0.0, 0.0], [2.0, 0.0], [np.nan, np.nan]]),
        covariances=np.array([np.zeros((2, 2)), 4.0 * np.eye(2), np.full((2, 2), np.nan)]),
        observable=np.array([True, True, False]),
        solver="tree",
    )
    scores = nees_per_agent(result, np.zeros((3, 2)))
    assert np.isnan(scores[0]) and scores[1] == pytest.approx(1.0) and np.isnan(scores[2])


# --------------------------------------------------------------------------- bad input


def args7() -> dict[str, object]:
    edges = np.array([(1, 2), (2, 3), (3, 4), (4, 5), (5, 6), (6, 7), (7, 1)])
    return {
        "n": 7,
        "d": 2,
        "edges": edges,
        "z": np.zeros((7, 2)),
        "cov": np.broadcast_to(np.eye(2), (7, 2, 2)).copy(),
        "ref": 1,
        "x_ref": np.zeros(2),
    }


@pytest.mark.parametrize(
    ("field", "value", "error", "message"),
    [
        ("z", np.zeros((5, 3)), ShapeError, r"^z has shape \(5, 3\); expected \(7, 2\)$"),
        ("cov", np.zeros((7, 2)), ShapeError, r"^cov has shape \(7, 2\); expected \(7, 2, 2\)$"),
        ("x_ref", np.zeros(3), ShapeError, r"^x_ref has shape \(3,\); expected \(2,\)$"),
        ("use", np.ones(6, dtype=bool), ShapeError, r"^use has shape \(6,\); expected \(7,\)$"),
        ("ref", 9, AgentIdError, r"^ref = 9; expected an agent id in 1\.\.7$"),
        ("ref", 0, AgentIdError, r"^ref = 0; expected an agent id in 1\.\.7$"),
        ("d", 0, GraphInputError, r"^d = 0; expected a dimension of at least 1$"),
        ("n", 0, GraphInputError, r"^n = 0; expected at least 1 agent$"),
        (
            "edges",
            np.array([(1, 2), (2, 3), (3, 4), (4, 5), (5, 6), (6, 8), (7, 1)]),
            AgentIdError,
            r"^edges\[5\] = \(6, 8\) names agent 8; expected ids in 1\.\.7$",
        ),
        (
            "z",
            np.array([[0.0, 0.0], [np.inf, 0.0]] + [[0.0, 0.0]] * 5),
            GraphInputError,
            r"^z\[1\] is not finite; expected finite measurements$",
        ),
    ],
)
def test_bad_input_says_expected_vs_actual(
    field: str, value: object, error: type, message: str
) -> None:
    kwargs = args7()
    kwargs[field] = value
    with pytest.raises(error, match=message):
        blue(**kwargs)  # type: ignore[arg-type]


def test_covariance_must_be_spd() -> None:
    kwargs = args7()
    cov = np.broadcast_to(np.eye(2), (7, 2, 2)).copy()
    cov[3] = np.diag([1.0, -1.0])
    with pytest.raises(
        CovarianceError,
        match=r"^cov\[3\] has smallest eigenvalue -1; expected a symmetric positive definite matrix$",
    ):
        blue(**{**kwargs, "cov": cov})  # type: ignore[arg-type]
    cov[3] = [[1.0, 2.0], [2.0, 1.0]]
    with pytest.raises(CovarianceError, match=r"^cov\[3\] has smallest eigenvalue -1; expected"):
        blue(**{**kwargs, "cov": cov})  # type: ignore[arg-type]
    cov[3] = [[1.0, 0.5], [0.0, 1.0]]
    with pytest.raises(
        CovarianceError,
        match=r"^cov\[3\] is not symmetric \(largest \|P − Pᵀ\| entry 0\.5\); expected",
    ):
        blue(**{**kwargs, "cov": cov})  # type: ignore[arg-type]
    assert isinstance(CovarianceError("a", "b"), ValueError)


def test_tree_solver_refuses_a_cycle() -> None:
    with pytest.raises(
        GraphInputError,
        match=r"^solver = 'tree' but the reference's component has 7 agents and 7 distinct used links; expected 6 \(a tree\)$",
    ):
        blue(**args7(), solver="tree")  # type: ignore[arg-type]
