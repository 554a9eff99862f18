"""Counter-based random numbers keyed by integers, e.g. ``(seed, stream, i, j, epoch)``.

A draw depends only on its key, never on how many draws came before, so every
process, in any order of calls, gets the same number for the same key (MODEL.md
§3, ARCHITECTURE.md "Time"). The hash is SplitMix64's finaliser chained over the
key words, vectorised with numpy so whole schedules are drawn at once.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np
import numpy.typing as npt

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MUL1 = np.uint64(0xBF58476D1CE4E5B9)
_MUL2 = np.uint64(0x94D049BB133111EB)
_TWO_POW_M53 = 2.0**-53

KeyLike = int | npt.ArrayLike


class Stream(IntEnum):
    """Separates the purposes a seed is used for, so their draws never coincide."""

    LOSS = 1  # netem: pass/drop and model state transitions
    DELAY = 2  # netem: delay and jitter
    NOISE = 3  # agents: relative measurement noise
    INITIAL = 4  # scenario: initial positions
    DUPLICATE = 5
    REORDER = 6
    SWEEP = 7  # experiments: per-cell seeds


def _mix(z: npt.NDArray[np.uint64]) -> npt.NDArray[np.uint64]:
    z = (z ^ (z >> np.uint64(30))) * _MUL1
    z = (z ^ (z >> np.uint64(27))) * _MUL2
    return z ^ (z >> np.uint64(31))


def keyed_bits(*keys: KeyLike) -> npt.NDArray[np.uint64]:
    """64 random bits per broadcast element of the integer key arrays (non-negative, < 2**63)."""
    arrays = [np.atleast_1d(np.asarray(k, dtype=np.int64)).astype(np.uint64) for k in keys]
    shape = np.broadcast_shapes(*(a.shape for a in arrays))
    h = np.full(shape, 0x243F6A8885A308D3, dtype=np.uint64)
    with np.errstate(over="ignore"):
        for a in arrays:
            h = _mix(h + _GOLDEN + _mix(a + _GOLDEN))
    return h


def keyed_uniform(*keys: KeyLike) -> npt.NDArray[np.float64]:
    """Uniform draws in [0, 1), one per broadcast element of the keys."""
    return (keyed_bits(*keys) >> np.uint64(11)).astype(np.float64) * _TWO_POW_M53


def keyed_normal(*keys: KeyLike) -> npt.NDArray[np.float64]:
    """Standard normal draws, one per broadcast element of the keys (Box–Muller)."""
    u1 = keyed_uniform(*keys, 0)
    u2 = keyed_uniform(*keys, 1)
    radius = np.sqrt(-2.0 * np.log1p(-u1))  # 1 - u1 in (0, 1]: log is finite
    return radius * np.cos(2.0 * np.pi * u2)


def keyed_normal_vector(d: int, *keys: KeyLike) -> npt.NDArray[np.float64]:
    """Standard normal vectors of length ``d``: shape ``broadcast(keys) + (d,)``."""
    coord = np.arange(d, dtype=np.int64)
    expanded = [np.asarray(k, dtype=np.int64)[..., None] for k in keys]
    return keyed_normal(*expanded, coord)
