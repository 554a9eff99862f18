"""Infinitesimal rigidity of the formation and of each epoch's healthy links (docs/model.md §2).

The math lives in ``formation.rigidity`` (the scenario loader checks the shape with
it); this module re-exports it under the leader's names and adds the per-epoch
check on the subgraph of healthy edges. A drop can cost the formation its
rigidity, which matters for the distance-based controller, and the leader
reports when it does.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from formation.graph import as_edge_array, as_edge_mask, as_positions
from formation.rigidity import SVD_MAX_COLUMNS, rigidity_rank
from formation.rigidity import expected_rigidity_rank as expected_rank
from formation.rigidity_check import is_rigid, rank_under_mask
from formation.rigidity_growth import growth_rounds, half_edges, spans_without_any

__all__ = [
    "UNKNOWN_RANK",
    "HealthyRigidity",
    "expected_rank",
    "healthy_rigidity",
    "is_rigid",
    "rigidity_rank",
]


def healthy_rigidity(
    positions: npt.ArrayLike, edges: npt.ArrayLike, healthy_mask: npt.ArrayLike
) -> tuple[int, bool]:
    """Rigidity rank of the healthy subgraph and whether it is infinitesimally rigid.

    Parameters
    ----------
    positions : (n, d) array_like [m]
        Where to evaluate the rigidity matrix, row ``i − 1`` = agent ``i``;
        generic positions such as the shape offsets ``d0`` (docs/model.md §2).
    edges : (m, 2) array_like of int
        The formation graph's edges, agent ids ``1..n``.
    healthy_mask : (m,) array_like of bool
        The edges healthy this epoch.

    Returns
    -------
    rank : int
        ``rank R(q)`` over the healthy edges (SVD, relative tolerance 1e-9).
    rigid : bool
        ``rank == expected_rank(n, d)``.
    """
    x = as_positions(positions)
    n, d = x.shape
    e = as_edge_array(n, edges)
    keep = as_edge_mask(healthy_mask, e.shape[0], "healthy_mask")
    rank = rigidity_rank(x, e[keep])
    return rank, rank == expected_rank(n, d)


UNKNOWN_RANK = -1
"""The rank the tracker reports where only rigid or not was known (docs/model.md §2)."""


class HealthyRigidity:
    """:func:`healthy_rigidity` for one formation, epoch after epoch, without an SVD per epoch.

    If the rows of the full rigidity matrix are independent (``rank == m``, as in
    every minimally rigid graph), every subset of them is independent too, so the
    healthy subgraph's rank is its number of edges. Otherwise a small formation
    (``n·d ≤ svd_max_columns``) ranks each distinct mask once by SVD and remembers it.
    A large one (:func:`formation.rigidity_check.rank_under_mask`) checks the growth order grown
    once on all edges (rigid: the rank is the expected one), then for an agent whose
    healthy edges cannot span (flexible, rank :data:`UNKNOWN_RANK`), then grows again
    and ranks the few agents growth leaves out by small SVDs (exact), and at last
    answers rigid or not by the pinned stiffness.
    """

    def __init__(
        self,
        positions: npt.ArrayLike,
        edges: npt.ArrayLike,
        svd_max_columns: int = SVD_MAX_COLUMNS,
    ) -> None:
        self.positions = as_positions(positions)
        n, d = self.positions.shape
        self.edges = as_edge_array(n, edges)
        self.expected = expected_rank(n, d)
        self.svd_max_columns = svd_max_columns
        self.small = n * d <= svd_max_columns or n <= d + 1
        m = self.edges.shape[0]
        self._seen: dict[bytes, int] = {}
        self._ranked_seen: dict[bytes, tuple[int, bool]] = {}
        if self.small:
            self.independent = rigidity_rank(self.positions, self.edges) == m
        else:  # more edges than the rank allows are dependent; exactly as many, iff rigid
            self.half = half_edges(self.positions, self.edges - 1)
            self.rounds = growth_rounds(self.positions, self.edges, half=self.half)
            self.spread = spans_without_any(self.positions)
            self.independent = m == self.expected and self._ranked(np.ones(m, dtype=bool))[1]

    def __call__(self, healthy_mask: npt.ArrayLike) -> tuple[int, bool]:
        """``(rank, rigid)`` of the healthy subgraph, as :func:`healthy_rigidity` gives them."""
        keep = as_edge_mask(healthy_mask, self.edges.shape[0], "healthy_mask")
        ranks, rigid = self.check(keep[None])
        return int(ranks[0]), bool(rigid[0])

    def check(
        self, healthy: npt.NDArray[np.bool_]
    ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.bool_]]:
        """Rank and rigidity of each of ``B`` healthy subgraphs: ``healthy`` (B, m) → (B,), (B,)."""
        counts: npt.NDArray[np.int64] = healthy.sum(axis=1, dtype=np.int64)
        if self.independent:
            return counts, counts == self.expected
        if self.small:
            ranks = np.zeros(healthy.shape[0], dtype=np.int64)
            for b, keep in enumerate(healthy):
                key = keep.tobytes()
                if key not in self._seen:
                    self._seen[key] = rigidity_rank(self.positions, self.edges[keep])
                ranks[b] = self._seen[key]
            return ranks, ranks == self.expected
        ranked = [self._ranked(k) for k in healthy]
        return (
            np.array([r for r, _ in ranked], dtype=np.int64),
            np.array([g for _, g in ranked], dtype=bool),
        )

    def _ranked(self, keep: npt.NDArray[np.bool_]) -> tuple[int, bool]:
        key = keep.tobytes()
        if key not in self._ranked_seen:
            rank, rigid = rank_under_mask(
                self.positions,
                self.edges,
                self.rounds,
                keep,
                self.spread,
                self.svd_max_columns,
                half=self.half,
            )
            self._ranked_seen[key] = (UNKNOWN_RANK if rank is None else rank), rigid
        return self._ranked_seen[key]
