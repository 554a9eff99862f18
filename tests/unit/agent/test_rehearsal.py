"""Before a realtime clock starts, the agents rehearse an epoch of their own work (its first
run costs several times the later ones): on copies, publishing nothing (in-memory bus)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from agent.node import AgentNode
from formation.scenario import Scenario
from shell import MemoryBus, Service

ROOT = Path(__file__).resolve().parents[3]
RUN = "rehearsal"


def test_an_agents_rehearsal_leaves_its_agents_as_they_were() -> None:
    scenario = Scenario.from_file(ROOT / "scenarios/grid20.toml")
    bus = MemoryBus()
    svc = Service(bus, RUN, "pool", 1)
    node = AgentNode(svc, scenario, [1, 2, 7], "estimate", seed=1)
    before = (node.runner.epoch, node.runner.x.copy(), node.runner.memory)
    node.rehearse()
    assert node.runner.epoch == before[0] == 0
    assert np.array_equal(node.runner.x, before[1])
    assert node.runner.memory is before[2]
    assert svc.sent == {} and dict(svc.malformed.counts) == {}
    assert node.inbox is None  # nothing filed: the inbox comes with the run's time policy
    assert node.deadline["in_time"] == 0
