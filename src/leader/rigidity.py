"""Infinitesimal rigidity of the formation and of each epoch's healthy links (MODEL.md §2).

The math lives in ``formation.graph`` (the scenario loader checks the shape with
it); this module re-exports it under the leader's names and adds the per-epoch
check on the subgraph of healthy edges. A drop can cost the formation its
rigidity, which matters for the distance-based controller, and the leader
reports when it does.
"""

from __future__ import annotations

import numpy.typing as npt

from formation.graph import (
    as_edge_array,
    as_edge_mask,
    as_positions,
    is_rigid,
    rigidity_rank,
)
from formation.graph import expected_rigidity_rank as expected_rank

__all__ = ["expected_rank", "healthy_rigidity", "is_rigid", "rigidity_rank"]


def healthy_rigidity(
    positions: npt.ArrayLike, edges: npt.ArrayLike, healthy_mask: npt.ArrayLike
) -> tuple[int, bool]:
    """Rigidity rank of the healthy subgraph and whether it is infinitesimally rigid.

    Parameters
    ----------
    positions : (n, d) array_like [m]
        Where to evaluate the rigidity matrix, row ``i − 1`` = agent ``i``;
        generic positions such as the shape offsets ``d0`` (MODEL.md §2).
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
