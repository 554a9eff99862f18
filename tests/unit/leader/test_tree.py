"""The tree solver's fused measurements are the same floats however their inverses are taken."""

from __future__ import annotations

import numpy as np

from leader.tree import _inverses, fuse_parallel


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
