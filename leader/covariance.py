"""Covariance blocks on a cyclic graph: selected inversion of the grounded Laplacian (docs/model.md §5).

``Cov(x̂_b) = A⁻¹`` with ``A = H_bᵀ P⁻¹ H_b`` SPD; the leader reports only its
``d × d`` diagonal blocks. With the fill-reducing factorisation ``A = Q L D Lᵀ Qᵀ``
(``L`` unit lower triangular, the sparse LU of ``leader.laplacian`` in symmetric
mode, which is an LDLᵀ), the entries of ``Z = (L D Lᵀ)⁻¹`` on the pattern of
``L`` follow from the Takahashi recurrences, column ``j`` from the later ones::

    Z[S_j, j] = −Z[S_j, S_j] L[S_j, j],     Z_jj = 1 / D_j − L[S_j, j]ᵀ Z[S_j, j]

(``S_j`` the rows below the diagonal of column ``j``: ancestors of ``j`` in the
elimination tree, a clique of the filled graph, so ``Z[S_j, S_j]`` is on the
pattern too). Nothing off the pattern is ever formed: exact, with the work of
the factorisation (Takahashi, Fagan, Chen 1973; Erisman, Tinney 1975).

Two ways to run the recurrence, chosen per column:

* **levels**: columns at the same depth of the elimination tree do not need
  each other, so all of a depth are done at once by flat gathers (each pair of the
  symmetric ``Z[S_j, S_j]`` once) and ``bincount`` sums (formation-like graphs: a
  few hundred depths);
* **core**: the columns whose ``|S_j|`` is large (the dense trailing fronts of an
  expander), closed under ancestors, are a trailing block of a valid elimination
  order, so ``Z`` on them is the dense inverse of their Schur complement,
  ``(L_CC D_C L_CCᵀ)⁻¹``, by LAPACK's ``potri`` on ``L_CC D_C^½``.

The split is chosen by a cost model (gathers against dense flops,
``CORE_*`` below; bench/bench_leader.py measured it). The result does not
depend on the split beyond rounding.

Everything but the arithmetic depends on ``L``'s pattern and the order only
(sorting, repairs, the tree, the split, the levels, every gather index): it is a
plan, made once and kept by the caller for the next factor of that pattern
(``leader.symbolic``), and reused only when the pattern is identical, so it never
changes the floats.
"""

from __future__ import annotations

import itertools
from collections.abc import Hashable, MutableMapping
from typing import Any, NamedTuple, Protocol

import numpy as np
import numpy.typing as npt
from scipy.linalg.lapack import dpotri
from scipy.sparse import csc_array

__all__ = ["LDLFactor", "PatternError", "inverse_diagonal_blocks"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

CORE_GATHER_S = 3e-8
"""Cost of one gathered pair ``a ≥ b`` of ``Z[S_j, S_j]`` on the levels [s] (measured with the
plan kept, the leader's steady state; building the plan costs about 1e-7 more, once)."""
CORE_FLOP_S = 5e-11
"""Cost of one flop of the dense core's inverse (``c³·2/3`` flops) [s] (measured)."""
CORE_THRESHOLDS = (8, 16, 32, 64, 128, 256, 512, 1024, 2048, 4096)
"""Column counts ``|S_j|`` tried as the core's threshold (and no core at all)."""
PATTERN_REPAIRS = 16
"""Restarts allowed to put back entries of ``L`` that the factorisation left out as zeros."""
LEVEL_CHUNK = 1 << 22
"""Most gathered entries held at once on one level (memory: ~40 bytes each)."""


class PatternError(RuntimeError):
    """The factor is not an ``L D Lᵀ`` this module can read; the caller computes the blocks
    another way."""


class LDLFactor(Protocol):
    """What is read of a symmetric-mode ``scipy.sparse.linalg.SuperLU``."""

    shape: tuple[int, int]
    perm_r: npt.NDArray[np.int32]
    perm_c: npt.NDArray[np.int32]

    @property
    def L(self) -> Any: ...  # SuperLU's names; a scipy sparse matrix

    @property
    def U(self) -> Any: ...


def inverse_diagonal_blocks(
    factor: LDLFactor,
    block: int,
    *,
    core: int | None = None,
    plans: MutableMapping[Hashable, Any] | None = None,
) -> FloatArray:
    """The ``block × block`` diagonal blocks of ``A⁻¹`` by selected inversion.

    Parameters
    ----------
    factor : SuperLU
        ``A``'s factorisation with symmetric pivoting (``perm_r == perm_c``, no
        row interchanges), so that ``U = D Lᵀ``.
    block : int
        Unknowns per node; node ``t``'s unknowns are ``t·block … t·block + block − 1``.
    core : int, optional
        Do the columns with ``|S_j| ≥ core`` (and their ancestors) densely; default:
        the threshold of least modelled cost. Any value gives the same blocks.
    plans : dict, optional
        Where the pattern-only part (elimination tree, levels, core, gather indices) is kept
        for the next factor of this pattern (``leader.symbolic``). It is reused only when
        ``L``'s pattern and the order are the same, so the blocks do not depend on it.

    Returns
    -------
    (N / block, block, block) float64 array
        ``(A⁻¹)[t·block + a, t·block + b]``, symmetric.

    Raises
    ------
    PatternError
        When the factor was not symmetric or a needed entry is off its pattern.
    """
    if not np.array_equal(factor.perm_r, factor.perm_c):
        raise PatternError("the factorisation pivoted rows; its L D Lᵀ is not A's")
    low = csc_array(factor.L)
    key = ("selected inversion", block, core)
    plan = None if plans is None else plans.get(key)
    if not isinstance(plan, _Plan) or not plan.fits(low, factor.perm_c):
        plan = _Plan(low, factor.perm_c, block, core)
        if plans is not None:
            plans[key] = plan
    return plan.blocks(low.data, factor.U.diagonal())


class _Plan:
    """What the selected inversion needs of ``L``'s pattern and the order, for many values.

    ``low``: ``L`` as SuperLU gives it (CSC, rows unsorted within a column); ``pos`` (N,):
    factor row of each unknown.
    """

    def __init__(
        self, low: csc_array, pos: npt.NDArray[np.int32], block: int, core: int | None
    ) -> None:
        self.raw_ptr, self.raw_idx, self.pos = low.indptr.copy(), low.indices.copy(), pos.copy()
        size = low.shape[0]
        ptr, idx = low.indptr.astype(np.int64), low.indices.astype(np.int64)
        column = np.repeat(np.arange(size, dtype=np.int64), np.diff(ptr))
        src = np.argsort(column * size + idx, kind="stable")  # rows sorted within each column
        idx = idx[src]
        if size and not np.array_equal(idx[ptr[:-1]], np.arange(size)):
            raise PatternError("a column of L does not start at its diagonal")
        at = pos.astype(np.int64)  # unknown u sits at row at[u] of the factor
        nodes = size // block
        a, b = np.triu_indices(block)
        i, k = at.reshape(nodes, block)[:, a].ravel(), at.reshape(nodes, block)[:, b].ravel()
        off = i != k
        wanted = np.minimum(i, k)[off] * size + np.maximum(i, k)[off]  # the blocks' own entries
        zero = low.data.size  # where L's values get a trailing 0.0
        for _ in range(PATTERN_REPAIRS):
            # SuperLU leaves out entries of L that came out exactly zero; the recurrence needs
            # its closed pattern, so they come back as zeros and it starts again
            ptr, idx, src = _with_entries(size, ptr, idx, src, wanted, zero)
            try:
                self.inverse = _SelectedInverse(size, ptr, idx, core)
                break
            except _OffPattern as missing:
                wanted = missing.keys
        else:
            raise PatternError(f"L's pattern still not closed after {PATTERN_REPAIRS} repairs")
        self.src = np.append(src, zero)  # one more 0.0 after L's entries, for the gathers
        self.out = self.inverse.sources(i, k)
        self.nodes, self.block, self.a, self.b = nodes, block, a, b

    @property
    def nbytes(self) -> int:
        """Memory held [bytes] (``leader.symbolic`` bounds its cache by it)."""
        inv = self.inverse
        arrays = [self.raw_ptr, self.raw_idx, self.pos, self.src, self.out, inv.ptr, inv.idx]
        arrays += [inv.keys, inv.core, inv.core_pos, inv.core_lens, inv.core_entry, inv.core_flat]
        arrays += [a for batch in inv.batches for a in batch if isinstance(a, np.ndarray)]
        return sum(a.nbytes for a in arrays)

    def fits(self, low: csc_array, pos: npt.NDArray[np.int32]) -> bool:
        """Whether ``low`` has this plan's pattern, in the same order."""
        return (
            np.array_equal(low.indptr, self.raw_ptr)
            and np.array_equal(low.indices, self.raw_idx)
            and np.array_equal(pos, self.pos)
        )

    def blocks(self, data: FloatArray, diag: FloatArray) -> FloatArray:
        """The diagonal blocks of ``A⁻¹`` from ``L``'s values (SuperLU's order) and ``D``."""
        val = np.append(data, 0.0)[self.src]
        got = self.inverse.invert(val, diag)[self.out].reshape(self.nodes, self.a.size)
        out = np.empty((self.nodes, self.block, self.block))
        out[:, self.a, self.b] = got
        out[:, self.b, self.a] = got
        return out


class _OffPattern(Exception):
    """Entries (keys ``col·N + row``) the recurrence needs that are not on the pattern."""

    def __init__(self, keys: IntArray) -> None:
        super().__init__(f"{keys.size} entries off the pattern")
        self.keys = keys


def _with_entries(
    size: int, ptr: IntArray, idx: IntArray, src: IntArray, keys: IntArray, zero: int
) -> tuple[IntArray, IntArray, IntArray]:
    """The CSC arrays of ``L`` with the entries ``keys`` (``col·N + row``) added; ``src`` says
    where each entry's value is, ``zero`` for the added ones."""
    have = np.repeat(np.arange(size, dtype=np.int64), np.diff(ptr)) * size + idx  # sorted
    at = np.minimum(np.searchsorted(have, keys), max(have.size - 1, 0))
    missing = keys[have[at] != keys] if have.size else keys
    if missing.size == 0:
        return ptr, idx, src
    new = np.unique(missing)
    merged = np.concatenate([have, new])
    order = np.argsort(merged, kind="stable")
    merged = merged[order]
    sources = np.concatenate([src, np.full(new.size, zero, dtype=np.int64)])[order]
    counts = np.bincount(merged // size, minlength=size)
    return np.concatenate([[0], np.cumsum(counts)]), merged % size, sources


class _Columns(NamedTuple):
    """One batch of columns done by flat gathers (:meth:`_SelectedInverse.invert`).

    cols (c,), steps: runs of columns that do not need each other; pairs, slots (c + 1,):
    where each column's pairs and ``S_j`` entries begin; per pair ``a ≥ b``: ``source`` of
    ``Z[S_j[a], S_j[b]]``, ``weight`` (``L[S_j[b], j]``) and ``mirror`` (``L[S_j[a], j]``, or
    the 0.0 on the diagonal) as indices into ``L``'s values, ``slot``/``slot_b`` in ``y``
    (local to the step); per entry of ``S_j``: ``entry`` in ``L`` and its column ``owner``
    (local to the step).
    """

    cols: IntArray
    steps: list[int]
    pairs: IntArray
    slots: IntArray
    source: IntArray
    weight: IntArray
    mirror: IntArray
    slot: IntArray
    slot_b: IntArray
    entry: IntArray
    owner: IntArray


class _SelectedInverse:
    """``Z = (L D Lᵀ)⁻¹`` on the pattern of ``L``: the structure once, :meth:`invert` per values.

    ``L`` (N, N) unit lower triangular as sorted CSC arrays ``ptr, idx`` (each column
    starting at its diagonal); ``threshold`` as ``core`` of :func:`inverse_diagonal_blocks`.
    Raises :class:`_OffPattern` when the pattern is not closed.
    """

    def __init__(self, size: int, ptr: IntArray, idx: IntArray, threshold: int | None) -> None:
        self.size = size
        self.ptr, self.idx = ptr, idx
        self.keys = np.repeat(np.arange(size, dtype=np.int64), np.diff(ptr)) * size + idx
        count = np.diff(ptr) - 1  # |S_j|
        parent = np.full(size, size, dtype=np.int64)
        has = count > 0
        parent[has] = idx[ptr[:-1][has] + 1]
        top = _subtree_max(count, parent)
        # |S_k| ≥ T somewhere in j's subtree: j is a descendant's ancestor, so in the core
        core = _choose_core(count, top) if threshold is None else top >= threshold
        self.core = np.flatnonzero(core)
        self.core_pos = np.full(size, -1, dtype=np.int64)
        self.core_pos[self.core] = np.arange(self.core.size)
        # Z in one flat store: on L's pattern (L's entry order), the diagonal, the dense core
        nnz, c = idx.size, self.core.size
        self.diag_at, self.core_at, self.stored = nnz, nnz + size, nnz + size + c * c
        # the core's entries of L: their place in L and in the store (the core column-major)
        starts, self.core_lens = ptr[self.core], ptr[self.core + 1] - ptr[self.core]
        lens = self.core_lens
        self.core_entry = np.repeat(starts - np.cumsum(lens) + lens, lens) + np.arange(
            int(lens.sum())
        )
        col = np.repeat(np.arange(c), lens)
        self.core_flat = self.core_at + col * c + self.core_pos[idx[self.core_entry]]
        depth = _depths(parent, core)
        rest = np.flatnonzero(~core)
        order = rest[np.argsort(depth[rest], kind="stable")]
        s = ptr[order + 1] - ptr[order] - 1
        self.batches = [
            self._columns(order[batch], s[batch], steps)
            for batch, steps in _batches(depth[order], s * (s + 1) // 2)
        ]

    def invert(self, val: FloatArray, diag: FloatArray) -> FloatArray:
        """The store of ``Z`` for ``L``'s values ``val`` (on the pattern, then one 0.0) and ``D``."""
        z = np.zeros(self.stored)
        self._core_inverse(z, val, diag)
        for batch in self.batches:
            self._takahashi(z, batch, val, diag)
        return z

    def _core_inverse(self, z: FloatArray, val: FloatArray, diag: FloatArray) -> None:
        """``(L_CC D_C L_CCᵀ)⁻¹``, dense: the Schur complement onto the core, inverted.

        Only the lower triangle is filled (column-major in the store): ``[i, k]`` with ``i ≥ k``
        is all that :meth:`sources` reads.
        """
        c = self.core.size
        if c == 0:
            return
        # R = L_CC D_C^½, so that R Rᵀ is the Schur complement; potri gives (R Rᵀ)⁻¹ in place
        scale = np.repeat(np.sqrt(diag[self.core]), self.core_lens)
        z[self.core_flat] = val[self.core_entry] * scale
        chol = z[self.core_at :].reshape((c, c), order="F")
        inv, info = dpotri(chol, lower=1, overwrite_c=1)
        if info != 0:
            raise PatternError(f"the core's factor is singular (LAPACK info {info})")
        if not np.shares_memory(inv, chol):
            chol[:] = inv
        z[self.diag_at + self.core] = np.diagonal(chol)

    def _columns(self, cols: IntArray, s: IntArray, steps: list[int]) -> _Columns:
        """The gathers of Takahashi's recurrence for the columns ``cols`` (|S_j| ``s``), in steps
        of columns that do not need each other (``steps``: where each begins, and the end).

        ``Z[S_j, S_j]`` is symmetric: each pair ``a ≥ b`` is gathered once and counts for
        ``y[a]`` (times ``L[S_j[b], j]``) and, off the diagonal, for ``y[b]``."""
        per = s * (s + 1) // 2
        first = self.ptr[cols] + 1  # where S_j starts in L's arrays
        offset = np.cumsum(s) - s  # where S_j starts among this batch's entries
        seg = np.repeat(np.arange(cols.size), per)
        t = np.arange(int(per.sum())) - np.repeat(np.cumsum(per) - per, per)
        ta, tb = _triangle(t)
        a, b = first[seg] + ta, first[seg] + tb  # entries (S_j[a], j), (S_j[b], j)
        source = self.sources(self.idx[a], self.idx[b])
        mirror = np.where(ta > tb, a, self.idx.size)  # the 0.0 after L's values
        # y[a] = Σ_b Z[S_j[a], S_j[b]] L[S_j[b], j]: pair (a, b) adds to slots a and b
        slot, slot_b = offset[seg] + ta, offset[seg] + tb
        owner = np.repeat(np.arange(cols.size), s)
        entry = first[owner] + np.arange(int(s.sum())) - offset[owner]
        pairs = np.concatenate([[0], np.cumsum(per)])
        slots = np.concatenate([[0], np.cumsum(s)])
        for c0, c1 in itertools.pairwise(steps):  # local to each step
            p0, p1, e0, e1 = pairs[c0], pairs[c1], slots[c0], slots[c1]
            slot[p0:p1] -= e0
            slot_b[p0:p1] -= e0
            owner[e0:e1] -= c0
        return _Columns(cols, steps, pairs, slots, source, b, mirror, slot, slot_b, entry, owner)

    def _takahashi(self, z: FloatArray, batch: _Columns, val: FloatArray, diag: FloatArray) -> None:
        """Takahashi's recurrence for one batch of columns, into the store ``z``."""
        pairs, slots, source, slot, slot_b, entry, owner = (
            batch.pairs,
            batch.slots,
            batch.source,
            batch.slot,
            batch.slot_b,
            batch.entry,
            batch.owner,
        )
        weight, mirror, on_entry = val[batch.weight], val[batch.mirror], val[entry]
        for c0, c1 in itertools.pairwise(batch.steps):
            p0, p1, e0, e1 = pairs[c0], pairs[c1], slots[c0], slots[c1]
            got = z[source[p0:p1]]
            y = np.bincount(slot[p0:p1], got * weight[p0:p1], minlength=e1 - e0)
            y += np.bincount(slot_b[p0:p1], got * mirror[p0:p1], minlength=e1 - e0)
            z[entry[e0:e1]] = -y
            done = batch.cols[c0:c1]
            z[self.diag_at + done] = 1.0 / diag[done] + np.bincount(
                owner[e0:e1], on_entry[e0:e1] * y, minlength=c1 - c0
            )

    def sources(self, i: IntArray, k: IntArray) -> IntArray:
        """Where ``Z[i, k]`` is in the store; raises :class:`_OffPattern` for pairs off the pattern."""
        hi, lo = np.maximum(i, k), np.minimum(i, k)
        out = np.empty(hi.size, dtype=np.int64)
        same = hi == lo
        out[same] = self.diag_at + hi[same]
        ci, ck = self.core_pos[hi], self.core_pos[lo]
        dense = ~same & (ck >= 0)  # on a closed pattern, hi is an ancestor: in the core too
        if (ci[dense] < 0).any():
            odd = dense & (ci < 0)
            raise _OffPattern(np.unique(lo[odd] * self.size + hi[odd]))
        out[dense] = self.core_at + ck[dense] * self.core.size + ci[dense]
        rest = ~same & ~dense
        key = lo[rest] * self.size + hi[rest]
        at = np.minimum(np.searchsorted(self.keys, key), max(self.keys.size - 1, 0))
        found = self.keys[at] == key
        if not found.all():
            raise _OffPattern(np.unique(key[~found]))
        out[rest] = at
        return out


def _triangle(t: IntArray) -> tuple[IntArray, IntArray]:
    """Row and column ``a ≥ b`` of the ``t``-th entry of a lower triangle stored row by row."""
    a = ((np.sqrt(8.0 * t + 1.0) - 1.0) / 2.0).astype(np.int64)
    a -= a * (a + 1) // 2 > t  # the square root's rounding, either way
    a += (a + 1) * (a + 2) // 2 <= t
    return a, t - a * (a + 1) // 2


def _batches(depth: IntArray, per: IntArray) -> list[tuple[slice, list[int]]]:
    """Columns sorted by depth, cut into batches of at most ``LEVEL_CHUNK`` gathers (one column
    at least), each with its steps: runs of one depth, local bounds ``[0, …, size]``."""
    out: list[tuple[slice, list[int]]] = []
    total = np.cumsum(per)
    start, size = 0, depth.size
    while start < size:
        base = total[start - 1] if start else 0
        stop = max(int(np.searchsorted(total, base + LEVEL_CHUNK, side="right")), start + 1)
        cuts = np.flatnonzero(np.diff(depth[start:stop])) + 1
        out.append((slice(start, stop), [0, *cuts.tolist(), stop - start]))
        start = stop
    return out


def _choose_core(count: IntArray, top: IntArray) -> BoolArray:
    """The columns done densely: those with ``|S_j| ≥ T`` and their ancestors (``top ≥ T``, ``top``
    from :func:`_subtree_max`), ``T`` by cost."""
    size = count.size
    work = count.astype(np.float64) * (count + 1) / 2
    best, best_cost = np.zeros(size, dtype=bool), CORE_GATHER_S * float(work.sum())
    for threshold in CORE_THRESHOLDS:
        if threshold > count.max(initial=0):
            break
        core = top >= threshold
        c = float(core.sum())
        cost = CORE_GATHER_S * float(work[~core].sum()) + CORE_FLOP_S * 2.0 / 3.0 * c**3
        if cost < best_cost:
            best, best_cost = core, cost
    return best


def _subtree_max(count: IntArray, parent: IntArray) -> IntArray:
    """Largest ``count`` in each column's subtree of the elimination tree, itself included
    (``parent[j] > j``; ``size``: a root), so ``top ≥ T`` is ``count ≥ T`` closed under ancestors."""
    top = count.tolist()
    par = parent.tolist()
    size = len(top)
    for j in range(size):
        p = par[j]
        if p < size and top[j] > top[p]:
            top[p] = top[j]
    return np.asarray(top, dtype=np.int64)


def _depths(parent: IntArray, core: BoolArray) -> IntArray:
    """Depth of each column below the core (or below its tree's root): a column after its parent."""
    size = parent.size
    depth = [0] * size
    par = parent.tolist()
    in_core = core.tolist()
    for j in range(size - 1, -1, -1):
        p = par[j]
        if not in_core[j] and p < size:
            depth[j] = depth[p] + 1
    return np.asarray(depth, dtype=np.int64)
