"""Keyed draws: fixed values (every recorded figure depends on them) and order independence."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from formation.compiled_keyed import chain, uniform_after
from formation.keyed_random import (
    _GOLDEN,
    COMPILED_FROM,
    _mix,
    _uniform,
    keyed_bits,
    keyed_normal_vector,
    keyed_uniform,
)


def test_draws_keep_their_values() -> None:
    # Values of the first implementation; a faster one must give the same bits.
    assert keyed_bits(1, 3, np.array([2, 5]), 7).tolist() == [
        1298727813646638646,
        16268291095379784883,
    ]
    assert keyed_uniform(42, 1, 2, 3, 9).tolist() == [0.9761377409195685]
    # The normals go through cos and log1p, which numpy dispatches by CPU (AVX-512 or not):
    # bit for bit on one machine (the equivalence tests), within an ulp across machines.
    normal = keyed_normal_vector(2, 1, 3, np.array([1, 2]), np.array([2, 1]), 4)
    first = np.array(
        [[-0.017598516292053126, 1.4399333776499879], [-1.130210593918367, -0.33492905362266645]]
    )
    assert np.all(np.abs(normal - first) <= 2 * np.spacing(np.abs(first)))


@given(
    st.integers(0, 2**62),
    st.lists(st.integers(0, 10**6), min_size=1, max_size=6),
    st.integers(0, 10**6),
)
def test_one_element_equals_its_row_of_a_batch(seed: int, senders: list[int], epoch: int) -> None:
    batch = keyed_normal_vector(3, seed, 3, np.array(senders), epoch)
    for r, j in enumerate(senders):
        assert np.array_equal(keyed_normal_vector(3, seed, 3, j, epoch), batch[r])
        assert np.array_equal(keyed_bits(seed, j, epoch), keyed_bits(seed, np.array([j]), epoch))


@given(
    st.lists(st.integers(0, 2**64 - 1), min_size=1, max_size=8),
    st.lists(st.integers(0, 2**63 - 1), min_size=1, max_size=8),
)
def test_the_compiled_chain_gives_numpys_bits(states: list[int], keys: list[int]) -> None:
    h = np.array(states, dtype=np.uint64)[:, None]
    key = np.array(keys, dtype=np.int64)[None, :]
    with np.errstate(over="ignore"):
        numpy_bits = _mix(h + _GOLDEN + _mix(key.astype(np.uint64) + _GOLDEN))
    assert np.array_equal(chain(h, key.astype(np.uint64)), numpy_bits)
    assert np.array_equal(uniform_after(h, key.astype(np.uint64)), _uniform(numpy_bits))


def test_draws_past_the_compiled_size_are_the_same_bits() -> None:
    links = np.arange(COMPILED_FROM // 64, dtype=np.int64)[:, None]
    epochs = np.arange(64, dtype=np.int64)[None, :]
    large = keyed_uniform(7, 1, links, 3, epochs)  # one step past the size: compiled
    assert np.array_equal(large[5], keyed_uniform(7, 1, links[5], 3, epochs)[0])
    assert np.array_equal(large[-1], keyed_uniform(7, 1, links[-1], 3, epochs)[0])
    normal = keyed_normal_vector(3, 7, links, epochs)  # (links, 64, 3): compiled
    assert np.array_equal(normal[9], keyed_normal_vector(3, 7, links[9], epochs)[0])
