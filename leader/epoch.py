"""One leader epoch (docs/model.md §4–§5): healthy edges → Kruskal tree → BLUE → rigidity.

Shared by the leader process and the in-process simulator, so both compute on
the same inputs in the same order and give the same floats.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from formation.scenario import Scenario
from leader.blue import BlueResult, blue
from leader.mst import minimum_spanning_forest
from leader.rigidity import HealthyRigidity

Array = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class LeaderEpoch:
    """What the leader knows after epoch ``k``.

    healthy, tree : (m,) per formation edge; components : forest components
    estimate : the BLUE (positions (n, d), covariances (n, d, d), observable (n,))
    rigidity_rank : rank of the healthy subgraph on the shape ``d0``; rigid : whether it is full
    """

    healthy: Mask
    tree: Mask
    components: int
    estimate: BlueResult
    rigidity_rank: int
    rigid: bool


def leader_epoch(
    scenario: Scenario, known: Mask, z: Array, x_ref: Array, rigidity: HealthyRigidity | None = None
) -> LeaderEpoch:
    """Process one epoch's reports.

    Parameters
    ----------
    scenario : the run's scenario; ``scenario.directed_links[l] = (j, i)`` is link ``j → i``
    known : (L,) the measurement of link ``l`` (taken by its receiver ``i``) reached the leader
    z : (L, d) ``z_ij = x_i − x_j + ε_ij`` where known [m]
    x_ref : (d,) the reference agent's position [m]
    rigidity : the scenario's rigidity tracker, kept across epochs (made here if None)
    """
    n, d = scenario.n, scenario.dimension
    edges, weights = scenario.edge_array, scenario.weights
    links = scenario.directed_links
    m = len(edges)
    per_edge = known.reshape(m, 2)
    rule_any = scenario.estimator.edge_rule == "either"
    healthy: Mask = np.asarray(
        per_edge.any(axis=1) if rule_any else per_edge.all(axis=1), dtype=bool
    )
    tree_idx = minimum_spanning_forest(n, edges, weights, healthy)
    tree = np.zeros(m, dtype=bool)
    tree[tree_idx] = True
    use_edge = tree if scenario.estimator.edges == "tree" else healthy
    use = known & np.repeat(use_edge, 2)
    oriented = links[use][:, ::-1]  # (receiver i, sender j): z = x_i − x_j
    noise = scenario.noise_covariance
    exact = not np.any(noise)  # ideal sensors: any equal weighting is exact
    cov = np.broadcast_to(np.eye(d) if exact else noise, (int(use.sum()), d, d))
    estimate = blue(n, d, oriented, z[use], cov, scenario.leader, x_ref)
    if exact and estimate.covariances is not None:
        estimate = replace(
            estimate, covariances=np.where(np.isnan(estimate.covariances), np.nan, 0.0)
        )
    rigidity = rigidity or HealthyRigidity(scenario.offsets, edges)
    rank, rigid = rigidity(healthy)
    return LeaderEpoch(
        healthy=healthy,
        tree=tree,
        components=n - len(tree_idx),
        estimate=estimate,
        rigidity_rank=int(rank),
        rigid=bool(rigid),
    )
