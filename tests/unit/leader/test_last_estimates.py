"""The leader leaves only once netem has its last estimates (``netem/final``, on the
in-memory bus)."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from formation import keys
from formation.scenario import Scenario
from leader.node import LeaderNode
from shell import MemoryBus, Query, Service

ROOT = Path(__file__).resolve().parents[3]
RUN = "last-messages"


@pytest.fixture
def scenario() -> Scenario:
    return Scenario.from_file(ROOT / "scenarios/paper.toml").with_overrides(epochs=10)


@pytest.mark.parametrize("done", [10, 3])
def test_the_leader_asks_for_its_last_estimates(
    scenario: Scenario, done: int, caplog: pytest.LogCaptureFixture
) -> None:
    asked: list[bytes] = []

    def on_final(query: Query) -> None:
        assert query.payload is not None
        asked.append(query.payload.to_bytes())
        query.reply(query.key_expr, f'{{"missing": [], "estimates_done": {done}}}'.encode())

    bus = MemoryBus()
    svc = Service(bus, RUN, "leader", 0)
    node = LeaderNode(svc, scenario)
    bus.declare_queryable(keys.netem_final(RUN), on_final)
    with caplog.at_level(logging.WARNING, logger="leader"):
        node.confirm_last()
    assert asked == [b'{"estimates":true}']
    warned = [r.getMessage() for r in caplog.records if r.name == "leader"]
    assert warned == (
        [] if done == scenario.epochs else ["netem has handled estimates of 3 epochs of 10"]
    )
