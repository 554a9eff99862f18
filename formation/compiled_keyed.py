"""The keyed hash's chaining step, compiled: :func:`formation.keyed_random._chain` on arrays as
one numba ufunc, a single pass over the broadcast keys where numpy makes a dozen.

Integer arithmetic modulo 2⁶⁴ only (xor, logical shifts, wrapping products), so every bit is
numpy's; ``tests/unit/formation/test_keyed_random.py`` holds the two equal.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MUL1 = np.uint64(0xBF58476D1CE4E5B9)
_MUL2 = np.uint64(0x94D049BB133111EB)
# shifts by uint64 amounts: a plain int would make numba type the uint64 operand as float
_S27, _S30, _S31 = np.uint64(27), np.uint64(30), np.uint64(31)


@numba.njit(inline="always")
def _mix(z: np.uint64) -> np.uint64:
    z = (z ^ (z >> _S30)) * _MUL1
    z = (z ^ (z >> _S27)) * _MUL2
    return z ^ (z >> _S31)


def _chain(h: np.uint64, key: np.uint64) -> np.uint64:
    return _mix(h + _GOLDEN + _mix(key + _GOLDEN))


_vectorize: Any = numba.vectorize  # untyped in numba
try:
    chain: np.ufunc = _vectorize(["uint64(uint64, uint64)"], cache=True)(_chain)
except RuntimeError:  # nowhere writable to cache: compile in this process
    chain = _vectorize(["uint64(uint64, uint64)"])(_chain)
"""``mix(h + G + mix(key + G))`` elementwise, ``h`` and ``key`` uint64 arrays broadcast together."""

__all__ = ["chain"]
