"""The tree solver's fused measurements are the same floats however their inverses are taken."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from leader.tree import _group_sums, _inverses, fuse_parallel, pair_groups


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
