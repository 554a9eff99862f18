"""Before a realtime clock starts, the agents and the leader rehearse an epoch of their own
work (its first run costs several times the later ones): on copies, publishing nothing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from agent.node import AgentNode
from formation.scenario import Scenario
from leader.node import LeaderNode
from testkit.zenoh_peer import peer_service

pytestmark = pytest.mark.integration
ROOT = Path(__file__).resolve().parents[2]
RUN = "rehearsal"


@pytest.fixture
def scenario() -> Scenario:
    return Scenario.from_file(ROOT / "scenarios/grid20.toml")


def test_an_agents_rehearsal_leaves_its_agents_as_they_were(scenario: Scenario) -> None:
    with peer_service(RUN, "pool", 1) as svc:
        node = AgentNode(svc, scenario, [1, 2, 7], "estimate", seed=1)
        before = (node.runner.epoch, node.runner.x.copy(), node.runner.memory)
        node._rehearse()
        assert node.runner.epoch == before[0] == 0
        assert np.array_equal(node.runner.x, before[1])
        assert node.runner.memory is before[2]
        assert svc.sent == {} and dict(svc.malformed.counts) == {}
        assert all(not box.packets and not box.estimates for box in node.inbox.values())
        assert node.deadline["in_time"] == 0


def test_the_leaders_rehearsal_sends_nothing(scenario: Scenario) -> None:
    with peer_service(RUN, "leader", 0) as svc:
        node = LeaderNode(svc, scenario)
        node._rehearse()
        assert node.epoch == 0 and node.reports == {}
        assert svc.sent == {}
