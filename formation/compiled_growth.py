"""Vertex addition's rounds, compiled: :func:`formation.rigidity_growth.growth_rounds`'s loop
with the same rounds, candidates and determinant bound, float for float (docs/model.md §2).

A round whose candidates the bound does not all pass goes back to the caller, which ranks
those by the batched SVD (numpy's, the reference's) and resumes the loop with the agents
that join.
"""

from __future__ import annotations

import numpy as np

from formation.compiled import jit
from formation.graph import BoolArray, FloatArray, IntArray
from formation.rigidity import RANK_RTOL

DONE = 0
"""Growth stopped: every agent joined, or a round found no candidate."""
UNSURE = 1
"""A round has candidates the bound leaves to the SVD: :func:`grow`'s ``cand``, ``sure`` beside."""


@jit
def largest_determinant(rows: FloatArray) -> float:
    """The largest ``|δ|`` of ``d`` of the ``d + 1`` rows ``(d + 1, d)``, ``d`` in 2 or 3, NaN
    if one is: ``_largest_determinants`` of one candidate, in the same products and sums."""
    best = 0.0
    nan = False
    if rows.shape[1] == 2:
        for p, q in ((0, 1), (0, 2), (1, 2)):
            v = abs(rows[p, 0] * rows[q, 1] - rows[p, 1] * rows[q, 0])
            nan = nan or v != v
            best = max(best, v)
    else:
        for p, q, r in ((0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3)):
            a0, a1, a2 = rows[p, 0], rows[p, 1], rows[p, 2]
            b0, b1, b2 = rows[q, 0], rows[q, 1], rows[q, 2]
            c0, c1, c2 = rows[r, 0], rows[r, 1], rows[r, 2]
            v = abs(a0 * (b1 * c2 - b2 * c1) - a1 * (b0 * c2 - b2 * c0) + a2 * (b0 * c1 - b1 * c0))
            nan = nan or v != v
            best = max(best, v)
    return np.nan if nan else best


@jit
def bound_passes(
    dirs: FloatArray,
    head: IntArray,
    start: IntArray,
    inside: BoolArray,
    agent: int,
    count: int,
    scale: float,
    rows: FloatArray,
) -> bool:
    """``_surely_spanning`` of one candidate: its first ``d + 1`` unit directions into the
    cluster (missing ones zero) copied to ``rows``, their :func:`largest_determinant`
    against ``RANK_RTOL · √count · scale`` (``scale = d^((d−1)/2)``)."""
    d = dirs.shape[1]
    rows[:] = 0.0
    taken = 0
    for h in range(start[agent], start[agent + 1]):
        if taken == d + 1:
            break
        if inside[head[h]]:
            rows[taken] = dirs[h]
            taken += 1
    best = largest_determinant(rows)
    return best == best and best > RANK_RTOL * np.sqrt(np.float64(count)) * scale


@jit
def grow(
    added: IntArray,
    joining: int,
    k: int,
    size: int,
    head: IntArray,
    start: IntArray,
    dirs: FloatArray,
    scale: float,
    rounds: IntArray,
    inside: BoolArray,
    count: IntArray,
    stamp: IntArray,
    near: IntArray,
    cand: IntArray,
    sure: BoolArray,
) -> tuple[int, int, int, int]:
    """Rounds of vertex addition from ``added[:joining]`` joining at round ``k``.

    The state (``rounds``, ``inside``, ``count``, ``stamp``) is updated in place; ``near``
    holds ``2m`` agents, ``cand``, ``sure`` and ``added`` ``n``. ``scale`` is ``d^((d−1)/2)``
    for ``d`` in 2 or 3, else negative (no bound: every round goes back). Returns
    ``(DONE or UNSURE, k, size, candidates)``.
    """
    n = rounds.shape[0]
    d = dirs.shape[1]
    rows = np.zeros((d + 1, d))
    while True:
        for i in range(joining):
            rounds[added[i]] = k
            inside[added[i]] = True
        size += joining
        if size == n:
            return DONE, k, size, 0
        reached = 0  # the heads of the joining agents' half-edges, agent after agent
        for i in range(joining):
            a = added[i]
            for h in range(start[a], start[a + 1]):
                near[reached] = head[h]
                count[head[h]] += 1
                reached += 1
        k += 1
        found = 0
        if size - joining <= d:  # the simplex, or the round that completes it
            for a in range(n):
                if not inside[a] and (count[a] == size if size <= d else count[a] >= d):
                    cand[found] = a
                    found += 1
        else:  # only the last round's neighbours gained edges into the cluster
            kept = 0
            for i in range(reached):
                b = near[i]
                if count[b] >= d and not inside[b]:
                    near[kept] = b
                    kept += 1
            for i in range(kept):
                stamp[near[i]] = i
            for i in range(kept):
                if stamp[near[i]] == i:  # each agent once, at its last place
                    cand[found] = near[i]
                    found += 1
        if found == 0:
            return DONE, k, size, 0
        unsure = scale < 0.0
        for i in range(found):
            sure[i] = not unsure and bound_passes(
                dirs, head, start, inside, cand[i], count[cand[i]], scale, rows
            )
            unsure = unsure or not sure[i]
        if unsure:
            return UNSURE, k, size, found
        joining = 1 if size <= d else found  # a simplex grows one agent at a time
        for i in range(joining):
            added[i] = cand[i]
