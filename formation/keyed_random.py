"""Counter-based random numbers keyed by integers, e.g. ``(seed, stream, i, j, epoch)``.

A draw depends only on its key, never on how many draws came before, so every
process, in any order of calls, gets the same number for the same key (docs/model.md
§3, docs/architecture.md "Time"). The hash is SplitMix64's finaliser chained over the
key words, vectorised with numpy so whole schedules are drawn at once.
"""

from __future__ import annotations

import math
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
    AIR = 8  # netem's 802.11 medium: backoffs and shadowing


def _mix(z: npt.NDArray[np.uint64]) -> npt.NDArray[np.uint64]:
    z = (z ^ (z >> np.uint64(30))) * _MUL1
    z = (z ^ (z >> np.uint64(27))) * _MUL2
    return z ^ (z >> np.uint64(31))


_M64 = (1 << 64) - 1
_G, _C1, _C2 = int(_GOLDEN), int(_MUL1), int(_MUL2)
_START = 0x243F6A8885A308D3


def _mix_int(z: int) -> int:
    """``_mix`` on one Python int: a scalar key costs no numpy call (an agent draws a handful)."""
    z = ((z ^ (z >> 30)) * _C1) & _M64
    z = ((z ^ (z >> 27)) * _C2) & _M64
    return z ^ (z >> 31)


COMPILED_FROM = 1 << 18
"""Hashes in one chaining step (the keys broadcast) from which it runs compiled (:mod:`formation.compiled_keyed`):
the same bits, a pass over the keys instead of a dozen."""


def _chain(h: int | npt.NDArray[np.uint64], key: KeyLike) -> int | npt.NDArray[np.uint64]:
    """The hash state after one more key word: ``mix(h + G + mix(key + G))``."""
    if isinstance(h, int) and isinstance(key, (int, np.integer)):
        return _mix_int((h + _G + _mix_int((int(key) + _G) & _M64)) & _M64)
    return _chain_words(*_words(h, key))


def _chain_words(
    state: np.uint64 | npt.NDArray[np.uint64], a: npt.NDArray[np.uint64]
) -> npt.NDArray[np.uint64]:
    """:func:`_chain` of a state and a key word already as uint64 (:func:`_words`)."""
    if _compiled(state, a):
        from formation.compiled_keyed import chain

        return np.asarray(chain(state, a))
    with np.errstate(over="ignore"):
        return _mix(state + _GOLDEN + _mix(a + _GOLDEN))


def _uniform_after(h: int | npt.NDArray[np.uint64], key: KeyLike) -> npt.NDArray[np.float64]:
    """``_uniform`` of the hash state after one more key word."""
    if isinstance(h, int) and isinstance(key, (int, np.integer)):
        return _uniform(_as_bits(_chain(h, key)))
    state, a = _words(h, key)
    if _compiled(state, a):
        from formation.compiled_keyed import uniform_after

        return np.atleast_1d(np.asarray(uniform_after(state, a), dtype=np.float64))
    return _uniform(_as_bits(_chain_words(state, a)))


def _words(
    h: int | npt.NDArray[np.uint64], key: KeyLike
) -> tuple[np.uint64 | npt.NDArray[np.uint64], npt.NDArray[np.uint64]]:
    """The state and the key word as uint64, as the hash takes them."""
    return (np.uint64(h) if isinstance(h, int) else h), np.asarray(key, dtype=np.int64).astype(
        np.uint64
    )


def _compiled(state: np.uint64 | npt.NDArray[np.uint64], a: npt.NDArray[np.uint64]) -> bool:
    """Whether a step this large runs compiled: numba loads in about a second, so only the
    simulator's plans pay it, not an agent process's block of noise."""
    if a.size * np.size(state) < COMPILED_FROM:  # bounds the broadcast's size: most steps stop here
        return False
    return math.prod(np.broadcast_shapes(a.shape, np.shape(state))) >= COMPILED_FROM


def _state(keys: tuple[KeyLike, ...]) -> int | npt.NDArray[np.uint64]:
    h: int | npt.NDArray[np.uint64] = _START
    for k in keys:
        h = _chain(h, k)
    return h


def _as_bits(h: int | npt.NDArray[np.uint64]) -> npt.NDArray[np.uint64]:
    return np.atleast_1d(np.asarray(h, dtype=np.uint64))


def keyed_bits(*keys: KeyLike) -> npt.NDArray[np.uint64]:
    """64 random bits per broadcast element of the integer key arrays (non-negative, < 2**63)."""
    return _as_bits(_state(keys))


def _uniform(bits: npt.NDArray[np.uint64]) -> npt.NDArray[np.float64]:
    return (bits >> np.uint64(11)).astype(np.float64) * _TWO_POW_M53


def keyed_uniform(*keys: KeyLike) -> npt.NDArray[np.float64]:
    """Uniform draws in [0, 1), one per broadcast element of the keys."""
    return _uniform_after(_state(keys[:-1]), keys[-1])


def keyed_state(*keys: KeyLike) -> int | npt.NDArray[np.uint64]:
    """The hash state after ``keys``: a prefix many draws share, computed once
    (:func:`keyed_normal_after`)."""
    return _state(keys)


def keyed_normal_after(
    state: int | npt.NDArray[np.uint64], *keys: KeyLike
) -> npt.NDArray[np.float64]:
    """``keyed_normal(*prefix, *keys)`` from ``state = keyed_state(*prefix)``, bit for bit."""
    h = state
    for k in keys:
        h = _chain(h, k)
    return _box_muller(h)


def keyed_normal(*keys: KeyLike) -> npt.NDArray[np.float64]:
    """Standard normal draws, one per broadcast element of the keys (Box–Muller)."""
    return _box_muller(_state(keys))


def _box_muller(h: int | npt.NDArray[np.uint64]) -> npt.NDArray[np.float64]:
    # h is shared by both uniforms, keyed (*keys, 0) and (*keys, 1)
    u1 = _uniform_after(h, 0)
    u2 = _uniform_after(h, 1)
    radius = np.sqrt(-2.0 * np.log1p(-u1))  # 1 - u1 in (0, 1]: log is finite
    return radius * np.cos(2.0 * np.pi * u2)


def keyed_normal_vector(d: int, *keys: KeyLike) -> npt.NDArray[np.float64]:
    """Standard normal vectors of length ``d``: shape ``broadcast(keys) + (d,)``."""
    coord = np.arange(d, dtype=np.int64)
    expanded = [
        k if isinstance(k, (int, np.integer)) else np.asarray(k, dtype=np.int64)[..., None]
        for k in keys
    ]
    return keyed_normal(*expanded, coord)
