"""Relative-measurement noise: prehashed link keys give the same draws, bit for bit."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from agent.measurement import NoiseKeys, measurement_noise


@given(
    st.integers(0, 2**62),
    st.lists(st.tuples(st.integers(1, 10**4), st.integers(1, 10**4)), min_size=1, max_size=6),
    st.integers(0, 10**6),
)
def test_prehashed_links_draw_the_same_noise(
    seed: int, links: list[tuple[int, int]], epoch: int
) -> None:
    receivers, senders = (np.array(c) for c in zip(*links, strict=True))
    cov = np.array([[0.04, 0.01], [0.01, 0.09]])
    keys = NoiseKeys(seed, receivers, senders)
    assert np.array_equal(
        measurement_noise(cov, seed, receivers, senders, epoch, keys),
        measurement_noise(cov, seed, receivers, senders, epoch),
    )


@given(
    st.integers(0, 2**62),
    st.lists(st.tuples(st.integers(1, 10**4), st.integers(1, 10**4)), min_size=1, max_size=6),
    st.integers(0, 10**6),
    st.lists(st.integers(-3, 200), min_size=1, max_size=8),
)
def test_noise_drawn_in_blocks_of_epochs_is_the_same_bit_for_bit(
    seed: int, links: list[tuple[int, int]], start: int, steps: list[int]
) -> None:
    """One ``NoiseKeys`` asked epoch after epoch (forward across blocks, or back) draws what
    the unkeyed call draws for each epoch alone."""
    receivers, senders = (np.array(c) for c in zip(*links, strict=True))
    cov = np.array([[0.04, 0.01], [0.01, 0.09]])
    keys = NoiseKeys(seed, receivers, senders)
    epoch = start
    for step in steps:
        epoch = max(epoch + step, 0)
        assert np.array_equal(
            measurement_noise(cov, seed, receivers, senders, epoch, keys),
            measurement_noise(cov, seed, receivers, senders, epoch),
        )


def test_noise_of_a_noiseless_scenario_is_zero() -> None:
    keys = NoiseKeys(1, np.array([1, 2]), np.array([2, 1]))
    zero = np.zeros((2, 2))
    assert not np.any(measurement_noise(zero, 1, np.array([1, 2]), np.array([2, 1]), 5, keys))
