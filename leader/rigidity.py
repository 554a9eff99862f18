"""Infinitesimal rigidity of the formation and of each epoch's healthy links (docs/model.md §2).

The math lives in ``formation.graph`` (the scenario loader checks the shape with
it); this module re-exports it under the leader's names and adds the per-epoch
check on the subgraph of healthy edges. A drop can cost the formation its
rigidity, which matters for the distance-based controller, and the leader
reports when it does.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from formation.graph import (
    as_edge_array,
    as_edge_mask,
    as_positions,
    is_rigid,
    rigidity_rank,
)
from formation.graph import expected_rigidity_rank as expected_rank

__all__ = ["HealthyRigidity", "expected_rank", "healthy_rigidity", "is_rigid", "rigidity_rank"]


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


class HealthyRigidity:
    """:func:`healthy_rigidity` for one formation, epoch after epoch, without an SVD per epoch.

    If the rows of the full rigidity matrix are independent (``rank == m``, as in
    every minimally rigid graph), every subset of them is independent too, so the
    healthy subgraph's rank is its number of edges. Otherwise each distinct mask is
    ranked once by SVD and remembered.
    """

    def __init__(self, positions: npt.ArrayLike, edges: npt.ArrayLike) -> None:
        self.positions = as_positions(positions)
        n, d = self.positions.shape
        self.edges = as_edge_array(n, edges)
        self.expected = expected_rank(n, d)
        self.independent = rigidity_rank(self.positions, self.edges) == self.edges.shape[0]
        self._seen: dict[bytes, int] = {}

    def __call__(self, healthy_mask: npt.ArrayLike) -> tuple[int, bool]:
        """``(rank, rigid)`` of the healthy subgraph, as :func:`healthy_rigidity` gives them."""
        keep = as_edge_mask(healthy_mask, self.edges.shape[0], "healthy_mask")
        rank = int(self.ranks(keep[None])[0])
        return rank, rank == self.expected

    def ranks(self, healthy: npt.NDArray[np.bool_]) -> npt.NDArray[np.int64]:
        """Rigidity rank of each of ``B`` healthy subgraphs: ``healthy`` (B, m) → (B,)."""
        if self.independent:
            counts: npt.NDArray[np.int64] = healthy.sum(axis=1, dtype=np.int64)
            return counts
        out = np.zeros(healthy.shape[0], dtype=np.int64)
        for b, keep in enumerate(healthy):
            key = keep.tobytes()
            if key not in self._seen:
                self._seen[key] = rigidity_rank(self.positions, self.edges[keep])
            out[b] = self._seen[key]
        return out
