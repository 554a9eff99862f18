"""Before a realtime clock starts, the leader rehearses an epoch of its own work (its first
run costs several times the later ones): publishing nothing (in-memory bus)."""

from __future__ import annotations

from pathlib import Path

from formation.scenario import Scenario
from leader.node import LeaderNode
from shell import MemoryBus, Service

ROOT = Path(__file__).resolve().parents[3]
RUN = "rehearsal"


def test_the_leaders_rehearsal_sends_nothing() -> None:
    scenario = Scenario.from_file(ROOT / "scenarios/grid20.toml")
    svc = Service(MemoryBus(), RUN, "leader", 0)
    node = LeaderNode(svc, scenario)
    node.rehearse()
    assert node.epoch == 0 and node.inbox is None
    assert svc.sent == {}
