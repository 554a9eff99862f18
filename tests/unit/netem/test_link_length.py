"""netem's per-packet link length equals the simulator's vectorised one, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from netem.links.matrix import link_length, link_lengths


@pytest.mark.parametrize("d", [1, 2, 3])
def test_one_link_is_the_batch_to_the_last_bit(d: int) -> None:
    rng = np.random.default_rng(19)
    a = rng.normal(scale=rng.choice([1e-3, 1.0, 1e3], size=(50_000, 1)), size=(50_000, d))
    b = rng.normal(size=(50_000, d))
    batch = link_lengths(a, b)
    one = np.array([link_length(x, y) for x, y in zip(a.tolist(), b.tolist(), strict=True)])
    np.testing.assert_array_equal(one, batch)
    # The batch of a batch (the simulator's (members, links, d)) measures the same.
    np.testing.assert_array_equal(link_lengths(a.reshape(50, 1000, d), b.reshape(50, 1000, d)),
                                  batch.reshape(50, 1000))  # fmt: skip


def test_the_length_is_the_euclidean_distance() -> None:
    assert link_length([0.0, 0.0, 0.0], [1.0, 2.0, 2.0]) == 3.0
    assert link_lengths([[3.0, 0.0]], [[0.0, 4.0]]).tolist() == [5.0]
