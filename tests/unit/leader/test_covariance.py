"""Covariance blocks by selected inversion (leader.covariance, docs/model.md §5) against the dense inverse."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse import csc_array
from scipy.sparse.linalg import splu

from leader.covariance import PatternError, inverse_diagonal_blocks
from leader.estimation import blue
from leader.laplacian import GroundedSystem
from testkit.dense_oracle import dense_system
from testkit.leader_problems import TOL, Kind, block_system, noise, random_graph

PROPERTY = settings(max_examples=40, deadline=None, derandomize=True, database=None)


@PROPERTY
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(2, 300),
    d=st.sampled_from([2, 3]),
    kind=st.sampled_from(["diagonal", "full", "scaled"]),
    shape=st.sampled_from(["cyclic", "tree"]),
    cycles=st.floats(0.05, 2.0),
    unobservable=st.integers(0, 12),
)
def test_every_block_equals_the_dense_inverse(
    seed: int, n: int, d: int, kind: Kind, shape: str, cycles: float, unobservable: int
) -> None:
    rng = np.random.default_rng(seed)
    edges = random_graph(rng, n, max(1, int(cycles * n)), shape == "tree")
    # agents n+1 .. n+u: a second component (or loners) the reference cannot see
    stray = random_graph(rng, unobservable, unobservable // 2, False) + n if unobservable else None
    total = n + unobservable
    if stray is not None and unobservable > 1:
        edges = np.concatenate([edges, stray])
    cov = noise(rng, len(edges), d, kind)
    z = rng.standard_normal((len(edges), d))
    ref = int(rng.integers(1, n + 1))
    # "direct": the grounded system and its factor even on a tree (auto would sum paths)
    got = blue(total, d, edges, z, cov, ref, np.zeros(d), solver="direct")
    assert got.covariances is not None
    observable = np.arange(total) < n
    assert np.array_equal(got.observable, observable)
    want = dense_system(total, edges, z, cov, ref, observable=observable).solve()[1]
    assert np.isnan(got.covariances[~observable]).all()
    err = np.abs(got.covariances[observable] - want[observable]).max()
    assert err <= TOL, f"max |Δ| = {err:.3g}"


def symmetric_lu(mat: csc_array):  # type: ignore[no-untyped-def]
    return splu(
        mat, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}
    )


@pytest.mark.parametrize("core", [None, 0, 3, 10**9])
@pytest.mark.parametrize("block", [1, 2, 3])
def test_dense_core_and_levels_give_the_same_blocks(
    seed: int, core: int | None, block: int
) -> None:
    rng = np.random.default_rng(seed)
    mat = block_system(rng, 150, block, 400)
    want = np.linalg.inv(mat.toarray()).reshape(150, block, 150, block)
    want = want[np.arange(150), :, np.arange(150), :]
    got = inverse_diagonal_blocks(symmetric_lu(mat), block, core=core)
    assert np.abs(got - want).max() <= 1e-12 * np.abs(want).max()


def test_a_factor_that_pivoted_rows_is_refused() -> None:
    # column 0's largest entry is off the diagonal: threshold pivoting swaps the rows
    mat = csc_array(np.array([[1.0, 2.0], [2.0, 5.0]]))
    lu = splu(mat, permc_spec="NATURAL", diag_pivot_thresh=1.0)
    assert not np.array_equal(lu.perm_r, lu.perm_c)
    with pytest.raises(PatternError, match="pivoted rows"):
        inverse_diagonal_blocks(lu, 1)


@PROPERTY
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(3, 200),
    d=st.sampled_from([2, 3]),
    odd_edge=st.booleans(),
)
def test_kronecker_path_only_when_every_covariance_is_a_multiple_of_one(
    seed: int, n: int, d: int, odd_edge: bool
) -> None:
    rng = np.random.default_rng(seed)
    edges = random_graph(rng, n, n // 2 + 1, False)
    cov = noise(rng, len(edges), d, "scaled")
    if odd_edge:  # one edge's noise is not a multiple of the others'
        k = int(rng.integers(len(edges)))
        cov[k] += np.diag(rng.uniform(0.1, 1.0, d)) * np.abs(cov[k]).max()
    z = rng.standard_normal((len(edges), d))
    everyone = np.ones(n, dtype=bool)
    system = GroundedSystem(n, 0, everyone, edges - 1, z, cov, np.zeros(d), diagonal=False)
    assert (system.shape is None) == odd_edge
    assert system.block == (d if odd_edge else 1)
    positions, blocks = np.zeros((n, d)), np.zeros((n, d, d))
    system.solve("direct", positions, blocks)
    want_x, want = dense_system(n, edges, z, cov).solve()
    assert np.abs(blocks[1:] - want[1:]).max() <= TOL
    assert np.abs(positions[1:] - want_x[1:]).max() <= TOL
