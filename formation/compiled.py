"""numba's compiler as every compiled loop of the testbed takes it: one place for its options."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba

F = TypeVar("F", bound=Callable[..., Any])


def jit(fn: F) -> F:
    """``numba.njit``, its machine code kept on disk beside the module (or in the user's
    cache, or ``NUMBA_CACHE_DIR``) so a process loads it; where none of them is writable
    (a read-only install and home) numba refuses to cache, and it compiles in each process."""
    return _compiled(fn)


def jit_inlined(fn: F) -> F:
    """``jit`` for a helper of a hot loop: numba writes its body into each compiled caller
    (``inline="always"``), which sheds the reference count that each array argument of a
    call costs on entry and on exit."""
    return _compiled(fn, inline="always")


def _compiled(fn: F, **options: Any) -> F:
    try:
        return cast(F, numba.njit(cache=True, nogil=True, **options)(fn))
    except RuntimeError:
        return cast(F, numba.njit(nogil=True, **options)(fn))


__all__ = ["jit", "jit_inlined"]
