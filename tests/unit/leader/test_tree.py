"""The tree solver's fused measurements are the same floats however their inverses are taken,
and its sums the same whether the structure of repeated links was kept or not."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from leader import tree
from leader.tree import _group_sums, _inverses, fuse_parallel, pair_groups, tree_solve


def test_inverses_of_a_stack_are_numpys_to_the_bit() -> None:
    rng = np.random.default_rng(7)
    a = rng.normal(size=(3, 3))
    one = a @ a.T + 3 * np.eye(3)
    same = np.repeat(one[None], 500, axis=0)
    mixed = same.copy()
    mixed[::7] *= 2.0
    for stack in (same, mixed, same[:1], same[:0]):
        np.testing.assert_array_equal(_inverses(stack), np.linalg.inv(stack))


def test_both_directions_of_a_link_fuse_into_one_measurement() -> None:
    e = np.array([[0, 1], [1, 0], [1, 2]])
    z = np.array([[1.0, 0.0], [-1.2, 0.0], [0.0, 2.0]])
    p = np.repeat((0.01 * np.eye(2))[None], 3, axis=0)
    fused_e, fused_z, fused_p = fuse_parallel(3, e, z, p)
    np.testing.assert_array_equal(fused_e, [[0, 1], [1, 2]])
    np.testing.assert_allclose(fused_z, [[1.1, 0.0], [0.0, 2.0]])
    np.testing.assert_allclose(fused_p[0], 0.005 * np.eye(2))


def test_group_sums_are_np_add_at_to_the_bit() -> None:
    rng = np.random.default_rng(11)
    group = rng.integers(0, 40, size=300)
    for values in (rng.normal(size=(300, 3, 3)) * 1e3, rng.normal(size=(300, 2))):
        want = np.zeros((45, *values.shape[1:]))
        np.add.at(want, group, values)
        assert _group_sums(group, values, 45).tobytes() == want.tobytes()


def test_a_fused_pair_is_the_information_weighted_sum_of_its_measurements() -> None:
    rng = np.random.default_rng(12)
    e = np.array([[0, 1], [1, 0], [0, 1], [2, 1]])
    z = rng.normal(size=(4, 2))
    a = rng.normal(size=(4, 2, 2))
    p = a @ a.transpose(0, 2, 1) + np.eye(2)
    fused_e, fused_z, fused_p = fuse_parallel(3, e, z, p)
    info = np.linalg.inv(p[:3])
    signed = z[:3] * np.array([1.0, -1.0, 1.0])[:, None]  # every one as x_0 − x_1
    want_p = np.linalg.inv(info.sum(axis=0))
    np.testing.assert_array_equal(fused_e, [[0, 1], [2, 1]])
    np.testing.assert_allclose(fused_p[0], want_p)
    np.testing.assert_allclose(fused_z[0], want_p @ np.einsum("eab,eb->a", info, signed))
    np.testing.assert_array_equal(fused_z[1], z[3])


@given(st.lists(st.integers(0, 40), max_size=60), st.booleans())
def test_pair_groups_are_np_unique(pairs: list[int], huge: bool) -> None:
    pair = np.array(pairs, dtype=np.int64) + (2**61 if huge else 0)  # huge: np.unique itself
    want = np.unique(pair, return_index=True, return_inverse=True, return_counts=True)
    for got, expected in zip(pair_groups(pair), want, strict=True):
        assert got.dtype == expected.dtype
        np.testing.assert_array_equal(got, expected)


def _solve(n: int, e: np.ndarray, z: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    fe, fz, fp = fuse_parallel(n, e, z, p)
    positions, blocks = np.full((n, 2), np.nan), np.full((n, 2, 2), np.nan)
    tree_solve(n, fe, fz, fp, np.array([0]), np.array([0.5, -1.0]), positions, blocks)
    return positions, blocks


def test_repeated_links_are_walked_once_and_give_the_same_floats(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = 300
    parent = np.array([int(rng.integers(0, v)) for v in range(1, n)])
    e = np.stack([np.arange(1, n), parent], axis=1)
    e = np.concatenate([e, e[::3, ::-1]])  # a third of the links measured both ways
    a = rng.normal(size=(len(e), 2, 2))
    p = a @ a.transpose(0, 2, 1) + np.eye(2)
    z1, z2 = rng.normal(size=(2, len(e), 2))
    tree._LastWalk.slot = tree._LastPairs.slot = None
    cold = _solve(n, e, z2, p)
    tree._LastWalk.slot = tree._LastPairs.slot = None
    _solve(n, e, z1, p)
    walk, pairs = tree._LastWalk.slot, tree._LastPairs.slot
    warm = _solve(n, e, z2, p)
    assert tree._LastWalk.slot is walk and tree._LastPairs.slot is pairs  # kept, not redone
    assert warm[0].tobytes() == cold[0].tobytes() and warm[1].tobytes() == cold[1].tobytes()
    cut = np.delete(np.arange(len(e)), 1)  # agent 2's one link gone: walked anew
    other = _solve(n, e[cut], z2[cut], p[cut])
    assert tree._LastWalk.slot is not walk and np.isnan(other[0][2]).all()
