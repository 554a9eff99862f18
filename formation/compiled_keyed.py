"""The keyed hash's chaining step, compiled: :func:`formation.keyed_random._chain` on arrays as
one numba ufunc, a single pass over the broadcast keys where numpy makes a dozen; and the last
step with its uniform.

Integer arithmetic modulo 2⁶⁴ (xor, logical shifts, wrapping products) and a uniform made of
53 bits by exact float steps, so every bit is numpy's; ``tests/unit/formation/test_keyed_random.py`` holds the two equal.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MUL1 = np.uint64(0xBF58476D1CE4E5B9)
_MUL2 = np.uint64(0x94D049BB133111EB)
# shifts by uint64 amounts: a plain int would make numba type the uint64 operand as float
_S11, _S27, _S30, _S31 = np.uint64(11), np.uint64(27), np.uint64(30), np.uint64(31)
_TWO_POW_M53 = 2.0**-53


@numba.njit(inline="always")
def _mix(z: np.uint64) -> np.uint64:
    z = (z ^ (z >> _S30)) * _MUL1
    z = (z ^ (z >> _S27)) * _MUL2
    return z ^ (z >> _S31)


@numba.njit(inline="always")
def _step(h: np.uint64, key: np.uint64) -> np.uint64:
    return _mix(h + _GOLDEN + _mix(key + _GOLDEN))


def _chain(h: np.uint64, key: np.uint64) -> np.uint64:
    return _step(h, key)


def _uniform_after(h: np.uint64, key: np.uint64) -> float:
    return np.float64(_step(h, key) >> _S11) * _TWO_POW_M53


def _ufunc(signature: str, fn: Any) -> np.ufunc:
    vectorize: Any = numba.vectorize  # untyped in numba
    try:
        return vectorize([signature], cache=True)(fn)  # type: ignore[no-any-return]
    except RuntimeError:  # nowhere writable to cache: compile in this process
        return vectorize([signature])(fn)  # type: ignore[no-any-return]


chain = _ufunc("uint64(uint64, uint64)", _chain)
"""``mix(h + G + mix(key + G))`` elementwise, ``h`` and ``key`` uint64 arrays broadcast together."""
uniform_after = _ufunc("float64(uint64, uint64)", _uniform_after)
"""The uniform in [0, 1) of :data:`chain`'s 53 high bits, as ``keyed_random._uniform`` makes it."""

__all__ = ["chain", "uniform_after"]
