"""The trust gate's checks of values: finite vectors of the team's dimension, rows finite as
one array, integer codes within a sorted set."""

from __future__ import annotations

import math
from collections.abc import Sequence
from itertools import chain
from typing import Any

import numpy as np
import numpy.typing as npt

from recorder.reading.skips import INVALID, Skip


def rows_of(rows: Sequence[Any], shape: tuple[int, ...]) -> npt.NDArray[np.float64] | None:
    """``rows`` (nested lists) as one float array of shape ``(len(rows), *shape)``, or None
    if one is not of ``shape`` or holds what is not a number; flattened level by level,
    which numpy's own discovery of a nested list's shape is several times slower than."""
    if not rows:
        return np.zeros((0, *shape))
    level: Sequence[Any] = rows
    try:
        for size in shape:
            if set(map(len, level)) != {size}:
                return None
            level = list(chain.from_iterable(level))
        return np.fromiter(level, float, len(level)).reshape(len(rows), *shape)
    except (ValueError, TypeError, OverflowError):  # no length, or not a number
        return None


def all_finite(rows: list[Any], shape: tuple[int | None, ...]) -> bool:
    """Whether ``rows`` are all of ``shape`` (None: any length) and finite, as one array."""
    if not rows:
        return True
    if None not in shape:
        known = rows_of(rows, tuple(s for s in shape if s is not None))
        return known is not None and bool(np.isfinite(known).all())
    try:
        arr = np.array(rows, dtype=float)
    except (ValueError, TypeError):
        return False  # ragged
    want = (len(rows), *shape)
    fits = arr.ndim == len(want) and all(
        w is None or w == a for w, a in zip(want, arr.shape, strict=True)
    )
    return bool(fits and np.isfinite(arr).all())


def within(values: npt.NDArray[np.int64], pool: npt.NDArray[np.int64]) -> bool:
    """Whether every value is in ``pool`` (sorted), by a binary search."""
    if not len(values):
        return True
    at = np.minimum(np.searchsorted(pool, values), max(len(pool) - 1, 0))
    return bool(len(pool) and (pool[at] == values).all())


def finite(values: Sequence[float], d: int | None, what: str) -> None:
    """Raise :class:`Skip` unless ``values`` has ``d`` components (None: any) all finite."""
    if d is not None and len(values) != d:
        raise Skip(INVALID, f"{what} has {len(values)} components, expected {d}")
    if not all(map(math.isfinite, values)):  # map: a million states a run at 10,000 agents
        raise Skip(INVALID, f"{what} is not finite")


__all__ = ["all_finite", "finite", "rows_of", "within"]
