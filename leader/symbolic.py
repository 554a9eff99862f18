"""Symbolic analysis of the grounded Laplacian, kept per sparsity pattern (docs/model.md §5).

What depends only on where the nonzeros are, and not on their values, is computed once per
pattern and reused while the pattern repeats, as sparse solvers split *analyse* from
*factorise* (CHOLMOD): the fill-reducing order, the gather that permutes the matrix by it,
and (kept by ``leader.covariance`` in :attr:`Analysis.plans`) the selected inversion's
elimination tree, levels, dense core and gather indices. The leader solves the BLUE every
epoch, and its healthy links repeat from epoch to epoch most of the time.

**Results never depend on the cache.** The order is computed from the pattern alone (minimum
degree on ``A + Aᵀ``, on a matrix of pattern-only values), and every factorisation, the first
for a pattern included, runs on the matrix explicitly permuted by it with SuperLU's natural
order: a cold and a warm call do the same arithmetic, bit for bit, so the batch simulator and
the leader process agree whatever each has cached.

The cache is per process and bounded (the least recently used of :data:`CACHE_PATTERNS`
patterns, and of :data:`CACHE_BYTES`). A lock guards its table; an :class:`Analysis` is not changed once made, except
that ``plans`` gains entries (two threads may both compute one, the same one). The leader
computes on one thread.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.sparse import csc_array, csr_array
from scipy.sparse.linalg import spilu, splu

__all__ = [
    "CACHE",
    "CACHE_BYTES",
    "CACHE_PATTERNS",
    "Analysis",
    "PermutedFactor",
    "SymbolicCache",
    "clear_cache",
    "factorise",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

CACHE_PATTERNS = 8
"""Patterns kept per process (the healthy sets an epoch loop alternates between)."""
CACHE_BYTES = 512 * 2**20
"""Older patterns are forgotten while the cache holds more than this [bytes] (an expander of
10,000 agents: 165 MB with its selected inversion's plan); the newest is always kept."""
_ORDER_DROP_TOL = 1e10
"""spilu drops every entry below this times its column's norm: only the order is wanted."""


class Analysis:
    """One sparsity pattern's symbolic analysis.

    ``order`` (N,): factor row ``k`` holds unknown ``order[k]``; ``position`` its inverse
    (unknown ``u`` at factor row ``position[u]``). ``take``, ``indices``, ``indptr``: the
    permuted matrix ``B = A[order][:, order]`` in CSC is ``(data[take], indices, indptr)``
    for ``A``'s CSR ``data``. ``plans``: what ``leader.covariance`` keeps for this pattern.
    """

    def __init__(self, mat: csr_array) -> None:
        size = mat.shape[0]
        self.size = size
        self.order: IntArray = np.argsort(_minimum_degree(mat)).astype(np.int64)
        self.position = np.empty(size, dtype=np.int64)
        self.position[self.order] = np.arange(size)
        row = np.repeat(np.arange(size, dtype=np.int64), np.diff(mat.indptr))
        col = mat.indices.astype(np.int64)
        # entry (r, c) of A is entry (position[r], position[c]) of B; CSC sorts by column first
        key = self.position[col] * size + self.position[row]
        self.take: IntArray = np.argsort(key, kind="stable")
        self.indices = (key[self.take] % size).astype(np.int32)
        counts = np.bincount(key[self.take] // size, minlength=size)
        self.indptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
        self.plans: dict[Any, Any] = {}

    @property
    def nbytes(self) -> int:
        """Memory held [bytes], the plans kept with it included."""
        arrays = (self.order, self.position, self.take, self.indices, self.indptr)
        plans = sum(int(getattr(plan, "nbytes", 0)) for plan in list(self.plans.values()))
        return sum(a.nbytes for a in arrays) + plans


class PermutedFactor:
    """``A = Q L D Lᵀ Qᵀ``: SuperLU's natural-order factor of ``A`` permuted by an
    :class:`Analysis`, read as ``leader.covariance.LDLFactor`` (``perm_c`` = ``perm_r`` =
    ``position``) and solved in ``A``'s numbering."""

    def __init__(self, analysis: Analysis, lu: Any) -> None:
        self.analysis = analysis
        self.plans = analysis.plans
        self.shape: tuple[int, int] = (analysis.size, analysis.size)
        self.perm_c = self.perm_r = analysis.position.astype(np.int32)
        self._lu = lu

    @property
    def L(self) -> Any:  # SuperLU's names
        return self._lu.L

    @property
    def U(self) -> Any:
        return self._lu.U

    def solve(self, rhs: FloatArray) -> FloatArray:
        """``A⁻¹ rhs`` for ``rhs`` (N,) or (N, k)."""
        order = self.analysis.order
        out = np.empty_like(rhs, dtype=np.float64)
        out[order] = self._lu.solve(np.asfortranarray(rhs[order]))
        return out


class SymbolicCache:
    """Least-recently-used analyses of up to ``capacity`` patterns, keyed by the exact pattern.

    When a pattern is added, the oldest are forgotten while more than ``capacity`` are kept or
    they hold more than ``max_bytes``. ``hits`` and ``misses`` count :meth:`analyse`'s lookups.
    """

    def __init__(self, capacity: int = CACHE_PATTERNS, max_bytes: int = CACHE_BYTES) -> None:
        if capacity < 1:
            raise ValueError(f"capacity = {capacity}; expected at least 1")
        self.capacity, self.max_bytes = capacity, max_bytes
        self.hits = 0
        self.misses = 0
        self._table: OrderedDict[tuple[int, str, bytes, bytes], Analysis] = OrderedDict()
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._table)

    def analyse(self, mat: csr_array) -> Analysis:
        """The analysis of ``mat``'s pattern (CSR, square, with its diagonal), made if new."""
        key = (mat.shape[0], mat.indices.dtype.str, mat.indptr.tobytes(), mat.indices.tobytes())
        with self._lock:
            found = self._table.get(key)
            if found is not None:
                self._table.move_to_end(key)
                self.hits += 1
                return found
            self.misses += 1
        made = Analysis(mat)  # outside the lock: milliseconds to seconds
        with self._lock:
            self._table[key] = made
            self._table.move_to_end(key)
            while len(self._table) > self.capacity or (
                len(self._table) > 1 and self.nbytes > self.max_bytes
            ):
                self._table.popitem(last=False)
        return made

    @property
    def nbytes(self) -> int:
        """Memory held by the analyses kept [bytes]."""
        return sum(analysis.nbytes for analysis in list(self._table.values()))

    def clear(self) -> None:
        """Forget every pattern and zero the counters."""
        with self._lock:
            self._table.clear()
            self.hits = self.misses = 0


CACHE = SymbolicCache()


def clear_cache() -> None:
    """Forget every analysis (a benchmark's cold start)."""
    CACHE.clear()


"""The process's cache (``leader.laplacian`` factorises through it)."""


def factorise(mat: csr_array, cache: SymbolicCache = CACHE) -> PermutedFactor:
    """Sparse ``L D Lᵀ`` of the SPD ``mat`` (CSR) in the fill-reducing order of its pattern."""
    analysis = cache.analyse(mat)
    size = analysis.size
    permuted = csc_array(
        (mat.data[analysis.take], analysis.indices, analysis.indptr), shape=(size, size)
    )
    # SPD: the diagonal pivots are safe (no row interchanges), so U = D Lᵀ
    lu = splu(
        permuted,
        permc_spec="NATURAL",
        diag_pivot_thresh=0.0,
        options={"SymmetricMode": True},
    )
    return PermutedFactor(analysis, lu)


def _minimum_degree(mat: csr_array) -> npt.NDArray[np.int32]:
    """SuperLU's minimum degree order on ``A + Aᵀ`` (``perm_c``: factor row of each unknown).

    SuperLU computes it from the structure alone, but scipy runs it only with a
    factorisation; an incomplete one that drops every entry is the cheapest. It is given
    values that depend on the pattern only (diagonally dominant: the column's count on the
    diagonal, −1 off it), so the order cannot depend on ``A``'s values.
    """
    size = mat.shape[0]
    count = np.diff(mat.indptr)
    row = np.repeat(np.arange(size), count)
    values = np.where(mat.indices == row, count[row].astype(np.float64), -1.0)
    pattern = csc_array((values, mat.indices, mat.indptr), shape=mat.shape)  # Aᵀ's: same A + Aᵀ
    ilu = spilu(
        pattern,
        drop_tol=_ORDER_DROP_TOL,
        fill_factor=1.0,
        drop_rule="basic",
        permc_spec="MMD_AT_PLUS_A",
        diag_pivot_thresh=0.0,
        options={"SymmetricMode": True},
    )
    order: npt.NDArray[np.int32] = ilu.perm_c
    return order
