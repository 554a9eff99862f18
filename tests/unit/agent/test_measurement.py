"""Relative-measurement noise: prehashed link keys give the same draws, bit for bit."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from agent.measurement import NoiseKeys, _correlate, measurement_noise
from formation.keyed_random import COMPILED_FROM


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


def test_zero_factors_skipped_leave_every_bit_of_the_full_sum() -> None:
    """``L·std`` summed over every column of the Cholesky factor, zeros included, from +0.0:
    the noise skips the zero factors and must keep those bits, signed zeros too."""
    std = np.random.default_rng(2).standard_normal((50, 3))
    std[0], std[1] = (-0.0, 0.0, -0.0), (1e-300, -1e-300, 5.0)
    for cov in (np.diag([0.01, 0.02, 0.03]), np.array([[2.0, 0.5, 0], [0.5, 1, 0.1], [0, 0.1, 3]])):
        chol = np.linalg.cholesky(cov)
        full = np.zeros((50, 3))
        for b in range(3):
            full += std[:, b : b + 1] * chol[:, b]
        got = _correlate(cov, lambda: std, (50,))
        assert np.array_equal(got, full) and np.array_equal(np.signbit(got), np.signbit(full))


def test_a_simulators_large_draw_is_an_agents_noise() -> None:
    """The simulator draws every link's noise over many epochs at once (compiled past
    ``COMPILED_FROM`` hashes); an agent draws its few links in numpy: the same bits."""
    cov = np.diag([0.04, 0.09, 0.01])
    links = np.arange(1, COMPILED_FROM // (3 * 64) + 2)
    epochs = np.arange(64)[:, None]
    everyone = measurement_noise(cov, 3, links[None, :] + 1, links[None, :], epochs)  # (64, L, 3)
    few = NoiseKeys(3, links[[0, -1]] + 1, links[[0, -1]])
    for k in (0, 63):
        assert np.array_equal(few.noise(cov, k), everyone[k, [0, -1]])
