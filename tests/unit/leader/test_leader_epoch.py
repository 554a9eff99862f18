"""The leader's epoch keeps the last Kruskal forest while the healthy edges stay the same."""

from __future__ import annotations

import numpy as np
import pytest

from leader.epoch import Leader
from testbed.sim.team_generators import henneberg_team


def test_the_forest_is_reused_only_while_the_healthy_edges_stay(seed: int) -> None:
    scenario = henneberg_team(40)
    rng = np.random.default_rng(seed)
    links = scenario.directed_links
    z = scenario.offsets[links[:, 1] - 1] - scenario.offsets[links[:, 0] - 1]
    z = z[None] + 0.01 * rng.standard_normal((2, *z.shape))
    known = rng.random((2, len(links))) < 0.9
    x_ref = scenario.offsets[scenario.reference_agent - 1]
    leader = Leader(scenario, None)
    first = leader.epochs(known, z, x_ref)
    again = leader.epochs(known, z[::-1], x_ref)  # new measurements, the same edges
    assert again.tree is first.tree
    with pytest.raises(ValueError, match="read-only"):
        again.tree[0, 0] = not again.tree[0, 0]  # shared by later epochs: never written
    cut = known.copy()
    cut[:, :4] = False  # both directions of edges 0 and 1
    other = leader.epochs(cut, z, x_ref)
    alone = Leader(scenario, None).epochs(cut, z, x_ref)
    assert other.tree is not first.tree and np.array_equal(other.tree, alone.tree)
    assert np.array_equal(other.estimate.positions, alone.estimate.positions, equal_nan=True)
