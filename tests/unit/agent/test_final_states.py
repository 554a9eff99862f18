"""An agent leaves only once netem has its last states: it republishes what netem's
``netem/final`` says it lacks (on the in-memory bus)."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest

from agent.node import AgentNode
from formation import keys
from formation.scenario import Scenario
from shell import MemoryBus, Query, Sample, Service

ROOT = Path(__file__).resolve().parents[3]
RUN = "last-messages"


@pytest.fixture
def scenario() -> Scenario:
    return Scenario.from_file(ROOT / "scenarios/paper.toml").with_overrides(epochs=10)


@pytest.mark.parametrize("answers", [[[2], []], [[2], [2], [2]]], ids=["acked", "never"])
def test_an_agent_republishes_the_final_states_netem_lacks(
    scenario: Scenario, answers: list[list[int]]
) -> None:
    published: Counter[int] = Counter()
    asked: list[bytes] = []

    def on_state(sample: Sample) -> None:
        published[int(str(sample.key_expr).split("/")[-2])] += 1

    def on_final(query: Query) -> None:
        assert query.payload is not None
        asked.append(query.payload.to_bytes())
        missing = answers[min(len(asked), len(answers)) - 1]
        query.reply(query.key_expr, f'{{"missing": {missing}, "estimates_done": 10}}'.encode())

    bus = MemoryBus()
    svc = Service(bus, RUN, "pool", 1)
    node = AgentNode(svc, scenario, [1, 2], "estimate", seed=1)
    bus.declare_subscriber(keys.agent_state(RUN, "*"), on_state)
    bus.declare_queryable(keys.netem_final(RUN), on_final)
    confirmed = node.confirm_final(timeout_s=0.0 if len(answers) > 2 else 10.0)
    svc.close()
    assert asked[0] == b'{"agents":[1,2]}'
    if answers[-1]:
        assert not confirmed and len(asked) == 1 and published == {2: 1}
    else:  # netem lacked agent 2's: published again, then acknowledged
        assert confirmed and len(asked) == 2 and published == {2: 1}


def test_an_agent_without_netem_leaves_at_once(scenario: Scenario) -> None:
    svc = Service(MemoryBus(), RUN, "agent", 1)
    node = AgentNode(svc, scenario, [1], "estimate", seed=1)
    assert node.confirm_final() is False  # nobody answers: nothing to wait for


@pytest.mark.parametrize("garbled", [b"not json", b"[2]"], ids=["not-json", "not-an-object"])
def test_a_garbled_answer_is_counted_and_the_agent_leaves(
    scenario: Scenario, garbled: bytes
) -> None:
    bus = MemoryBus()
    svc = Service(bus, RUN, "agent", 1)
    node = AgentNode(svc, scenario, [1], "estimate", seed=1)
    key = keys.netem_final(RUN)
    bus.declare_queryable(key, lambda q: q.reply(q.key_expr, garbled))
    assert node.confirm_final() is False
    assert svc.malformed.counts[key] == 1
