"""The leader's estimates without covariances first, the covariances after (issue 18 item 2)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from formation.errors import ScenarioError
from formation.messages import LeaderEstimate
from formation.scenario import Scenario, load_dict
from leader.epoch import Leader
from leader.rigidity import HealthyRigidity
from leader.wire import estimate_message
from testbed.sim.simulate import simulate
from testbed.sim.team_generators import henneberg_team

ROOT = Path(__file__).resolve().parents[3]
HEAD = {"run_id": "r", "sender": "leader", "seq": 0, "epoch": 3, "stamp_ns": 1}


def _reports(scenario: Scenario, size: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(B, L) known and (B, L, d) noisy ``z`` of every directed link, some lost."""
    rng = np.random.default_rng(seed)
    links = scenario.directed_links
    x = scenario.offsets
    z = x[links[:, 1] - 1] - x[links[:, 0] - 1]
    z = z[None] + 0.01 * rng.standard_normal((size, *z.shape))
    return rng.random((size, len(links))) < 0.8, z


@pytest.mark.parametrize("edges", ["tree", "healthy"])
@pytest.mark.parametrize("n", [5, 40])  # the dense solver, the sparse one
def test_covariances_after_the_estimates_equal_them_computed_together(
    n: int, edges: str, seed: int
) -> None:
    scenario = henneberg_team(n, estimator={"edges": edges})
    leader = Leader(scenario, HealthyRigidity(scenario.offsets, scenario.edge_array))
    known, z = _reports(scenario, 3, seed)
    x_ref = scenario.offsets[scenario.reference_agent - 1]
    together = leader.epochs(known, z, x_ref)
    first = leader.epochs(known, z, x_ref, covariances=False)
    assert first.estimate.covariances is None
    assert np.array_equal(first.estimate.positions, together.estimate.positions, equal_nan=True)
    after = leader.covariances(known, z, x_ref, first)
    assert together.estimate.covariances is not None
    assert np.array_equal(after, together.estimate.covariances, equal_nan=True)


def test_an_epoch_without_covariances_is_a_valid_message_with_none_blocks(seed: int) -> None:
    scenario = henneberg_team(30)
    leader = Leader(scenario, HealthyRigidity(scenario.offsets, scenario.edge_array))
    known, z = _reports(scenario, 1, seed)
    lead = leader.epochs(known, z, scenario.offsets[0], covariances=False).member(0)
    raw = estimate_message(HEAD, lead, [1.0, 2.0], [0.1, 0.2], scenario.edge_array, 29)
    msg = LeaderEstimate.model_validate_json(raw)
    assert msg.covariances == [None] * scenario.n
    assert msg.positions[1] == lead.estimate.positions[1].tolist()


def _paper(**estimator: Any) -> dict[str, Any]:
    data = Scenario.from_file(ROOT / "scenarios/paper.toml").model_dump(mode="json")
    data["estimator"] = {**data["estimator"], **estimator}
    return data


def test_covariance_every_must_be_a_positive_integer() -> None:
    with pytest.raises(ScenarioError, match=r"estimator\.covariance_every.*0"):
        load_dict(_paper(covariance_every=0), "k.toml")
    assert load_dict(_paper(covariance_every=4)).estimator.covariance_every == 4


def test_the_simulator_computes_covariances_on_every_kth_epoch_only() -> None:
    scenario = load_dict(_paper(covariance_every=3, edges="healthy"))
    cov = simulate(scenario, "estimate", seed=1).estimate_cov  # (E, n, d, d)
    has = ~np.isnan(cov[:, 1:]).all(axis=(1, 2, 3))  # agents 2..n: the reference's block is 0
    epochs = np.arange(scenario.epochs)
    assert np.array_equal(has, epochs % 3 == 0)
