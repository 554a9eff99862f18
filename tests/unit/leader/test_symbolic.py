"""The symbolic analysis kept per pattern (leader.symbolic, docs/model.md §5): reused, exact,
and without effect on the floats."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse import csc_array, csr_array
from scipy.sparse.linalg import splu

from leader.covariance import inverse_diagonal_blocks
from leader.estimation import BlueResult, MeasurementGraph, blue
from leader.symbolic import CACHE, SymbolicCache, factorise
from testkit.dense_oracle import dense_system
from testkit.leader_problems import TOL, Kind, block_system, noise, random_graph

KINDS: tuple[Kind, ...] = ("diagonal", "full", "scaled")


def run(edges: np.ndarray, z: np.ndarray, cov: np.ndarray, n: int) -> BlueResult:
    """Every agent's estimate and block by the factorisation, agent 1 at the origin."""
    return blue(n, cov.shape[1], edges, z, cov, 1, np.zeros(cov.shape[1]), solver="direct")


def check_dense(got: BlueResult, edges: np.ndarray, z: np.ndarray, cov: np.ndarray) -> None:
    n = got.positions.shape[0]
    x, c = dense_system(n, edges, z, cov).solve()
    assert got.covariances is not None
    assert np.abs(got.covariances[1:] - c[1:]).max() <= TOL
    assert np.abs(got.positions[1:] - x[1:]).max() <= TOL


@pytest.mark.parametrize("kind", KINDS)
def test_a_pattern_seen_again_is_reused_and_still_exact(seed: int, kind: Kind) -> None:
    rng = np.random.default_rng(seed)
    for _ in range(4):
        n = int(rng.integers(20, 90))
        first = random_graph(rng, n, n, False)
        other = random_graph(rng, n, n // 2, False)
        d = int(rng.choice([2, 3]))
        CACHE.clear()
        # the first pattern, another one, then the first twice with new measurements and noise
        for edges, new in ((first, True), (other, True), (first, False), (first, False)):
            cov = noise(rng, len(edges), d, kind)
            z = rng.standard_normal((len(edges), d))
            hits, misses = CACHE.hits, CACHE.misses
            check_dense(run(edges, z, cov, n), edges, z, cov)
            assert CACHE.misses == misses + new  # a new pattern is analysed once
            assert CACHE.hits > hits or new  # a pattern seen before is not analysed again
        assert len(CACHE) == 2


@pytest.mark.parametrize("kind", KINDS)
def test_cold_and_warm_give_the_same_floats(seed: int, kind: Kind) -> None:
    rng = np.random.default_rng(seed)
    n = 150
    edges = random_graph(rng, n, 2 * n, False)
    cov, other = noise(rng, len(edges), 2, kind), noise(rng, len(edges), 2, kind)
    z = rng.standard_normal((len(edges), 2))
    CACHE.clear()
    cold = run(edges, z, cov, n)
    run(edges, z, other, n)  # the same pattern with other values in between
    warm = run(edges, z, cov, n)
    assert CACHE.misses == 1 and CACHE.hits >= 2  # diagonal: one factor per coordinate
    assert cold.covariances is not None and warm.covariances is not None
    assert np.array_equal(cold.positions, warm.positions)
    assert np.array_equal(cold.covariances, warm.covariances)


def test_the_selected_inversion_plan_is_kept_with_the_pattern(seed: int) -> None:
    rng = np.random.default_rng(seed)
    mat = csr_array(block_system(rng, 120, 2, 300))
    cache = SymbolicCache()
    factor = factorise(mat, cache)
    inverse_diagonal_blocks(factor, 2, plans=factor.plans)
    (plan,) = factor.plans.values()
    again = factorise(csr_array((2.0 * mat.data, mat.indices, mat.indptr), shape=mat.shape), cache)
    assert again.analysis is factor.analysis
    blocks = inverse_diagonal_blocks(again, 2, plans=again.plans)
    assert next(iter(again.plans.values())) is plan
    want = np.linalg.inv(2.0 * mat.toarray()).reshape(120, 2, 120, 2)
    want = want[np.arange(120), :, np.arange(120), :]
    assert np.abs(blocks - want).max() <= 1e-12 * np.abs(want).max()


def test_a_factor_whose_pattern_lost_an_entry_gets_a_new_plan() -> None:
    # natural order; L[2, 1] = (a21 − L10 L20 D0) / D1 is exactly zero for a21 = 1 and
    # SuperLU leaves it out: the same matrix pattern, another pattern of L
    values = {"fill": 0.5, "cancel": 1.0}
    plans: dict[object, object] = {}
    kept = []
    for name in ("fill", "cancel", "fill"):
        a21 = values[name]
        dense = np.array([[1.0, 1.0, 1.0], [1.0, 2.0, a21], [1.0, a21, 2.0]])
        lu = splu(
            csc_array(dense),
            permc_spec="NATURAL",
            diag_pivot_thresh=0.0,
            options={"SymmetricMode": True},
        )
        got = inverse_diagonal_blocks(lu, 1, plans=plans)
        assert np.abs(got[:, 0, 0] - np.diag(np.linalg.inv(dense))).max() <= 1e-12
        kept.append(next(iter(plans.values())))
    assert kept[0] is not kept[1] and kept[1] is not kept[2]


def test_the_factor_solves_in_the_matrix_numbering(seed: int) -> None:
    rng = np.random.default_rng(seed)
    mat = csr_array(block_system(rng, 80, 3, 200))
    rhs = rng.standard_normal((mat.shape[0], 4))
    got = factorise(mat, SymbolicCache()).solve(rhs)
    assert np.abs(mat @ got - rhs).max() <= 1e-9 * np.abs(rhs).max()


def test_the_cache_keeps_the_most_recent_patterns(seed: int) -> None:
    rng = np.random.default_rng(seed)
    mats = [csr_array(block_system(rng, 30, 1, 20 + k)) for k in range(3)]
    cache = SymbolicCache(capacity=2)
    for mat in mats:
        cache.analyse(mat)
    assert len(cache) == 2 and cache.misses == 3
    cache.analyse(mats[2])
    assert cache.hits == 1
    cache.analyse(mats[0])  # the least recently used was forgotten
    assert cache.misses == 4
    with pytest.raises(ValueError, match="capacity = 0; expected at least 1"):
        SymbolicCache(capacity=0)


def test_the_cache_forgets_old_patterns_past_its_bytes(seed: int) -> None:
    rng = np.random.default_rng(seed)
    mats = [csr_array(block_system(rng, 60, 2, 100 + k)) for k in range(3)]
    one = SymbolicCache()
    factor = factorise(mats[0], one)
    bare = one.nbytes
    inverse_diagonal_blocks(factor, 2, plans=factor.plans)
    assert one.nbytes > bare > 0  # the plan kept with the pattern counts too
    cache = SymbolicCache(max_bytes=one.nbytes)  # one pattern with its plan, not two
    for mat in mats:
        factor = factorise(mat, cache)
        inverse_diagonal_blocks(factor, 2, plans=factor.plans)
    assert len(cache) == 1 and cache.misses == 3
    cache.analyse(mats[2])  # the newest is kept
    assert cache.hits == 1


def test_the_order_depends_on_the_pattern_only(seed: int) -> None:
    rng = np.random.default_rng(seed)
    mat = csr_array(block_system(rng, 100, 1, 250))
    scaled = csr_array((rng.uniform(0.5, 2.0, mat.nnz) * mat.data, mat.indices, mat.indptr))
    first = SymbolicCache().analyse(mat)
    second = SymbolicCache().analyse(scaled)
    assert np.array_equal(first.order, second.order)
    # and it is SuperLU's minimum degree on A + Aᵀ
    lu = splu(
        mat.tocsc(),
        permc_spec="MMD_AT_PLUS_A",
        diag_pivot_thresh=0.0,
        options={"SymmetricMode": True},
    )
    assert np.array_equal(first.position, lu.perm_c)


@pytest.mark.parametrize("kind", KINDS)
def test_a_batch_member_gets_the_floats_it_gets_alone_whatever_was_cached(
    seed: int, kind: Kind
) -> None:
    # the simulator's batch sees other members' patterns first, a leader process only its own
    rng = np.random.default_rng(seed)
    n, d = 80, 2
    edges = random_graph(rng, n, n, False)
    cov = noise(rng, len(edges), d, kind)
    graph = MeasurementGraph.of(n, d, edges, cov, 1)
    links = rng.random((2, len(edges))) < 0.9
    links[:, : n - 1] = True  # the spanning tree: everyone observable
    use = links[[0, 1, 0, 0]]  # members 2 and 3 repeat member 0's links
    z = rng.standard_normal((4, len(edges), d))
    CACHE.clear()
    batch = graph.estimate(z, np.zeros(d), use)
    assert set(batch.solvers) == {"direct"}
    for b in (3, 1, 0, 2):
        for cached in (False, True):
            if not cached:
                CACHE.clear()
            alone = blue(n, d, edges, z[b], cov, 1, np.zeros(d), use[b])
            assert alone.covariances is not None and batch.covariances is not None
            assert np.array_equal(alone.positions, batch.positions[b])
            assert np.array_equal(alone.covariances, batch.covariances[b])


def test_the_permuted_factor_is_superlus_own_to_rounding(seed: int) -> None:
    rng = np.random.default_rng(seed)
    mat = csr_array(block_system(rng, 150, 1, 300))
    ours = factorise(mat, SymbolicCache())
    theirs = splu(
        mat.tocsc(),
        permc_spec="MMD_AT_PLUS_A",
        diag_pivot_thresh=0.0,
        options={"SymmetricMode": True},
    )
    assert np.array_equal(ours.perm_c, theirs.perm_c)
    for mine, other in ((ours.L, theirs.L), (ours.U, theirs.U)):
        a, b = csc_array(mine), csc_array(other)
        a.sort_indices()
        b.sort_indices()
        assert np.array_equal(a.indptr, b.indptr) and np.array_equal(a.indices, b.indices)
        assert np.abs(a.data - b.data).max() <= 1e-12 * np.abs(b.data).max()
