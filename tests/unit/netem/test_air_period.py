"""The reports in the states' contention period (``network.air.reports = "with_states"``), on
the states' channel or on one of their own: what it changes, and netem's lockstep deciding it
as the simulator does."""

from __future__ import annotations

from typing import Any

import pytest

import testbed
from formation.keys import LEADER_ENDPOINT
from formation.scenario import Scenario
from netem.links.air_network import AIR, AirNetwork

from .test_air_network import lockstep_records, on_air


def test_the_reports_in_the_states_period_change_a_states_fate_and_not_on_their_own_channel(
    paper: Scenario,
) -> None:
    x = paper.initial_positions(3)
    states = [(int(a), int(b)) for a, b in paper.directed_links]
    reports = [(i, LEADER_ENDPOINT) for i in range(1, paper.n + 1)]
    after = AirNetwork(on_air(paper, 5), 3)
    shared = AirNetwork(on_air(paper, 5, reports="with_states"), 3)
    own = AirNetwork(on_air(paper, 5, reports="with_states", control_channel="own"), 3)
    changed = 0
    for k in range(20):
        alone = after.phase(k, "state", states, x)
        with_reports, shared_reports = shared.with_states(k, states, reports, x)
        own_states, own_reports = own.with_states(k, states, reports, x)
        assert own_states == alone  # the reports on a channel of their own: no state meets one
        # a state and a report from each agent, in one phase
        assert {v.frames for v in with_reports + shared_reports} == {paper.n * 2}
        assert {v.frames for v in own_reports} == {paper.n}
        changed += with_reports != alone
    assert changed > 0


def decided_alike(scenario: Scenario, seed: int) -> list[Any]:
    """netem's lockstep records of ``scenario``, each checked against the simulator's."""
    sim = testbed.simulate(scenario, seed=seed)
    made = sim.decisions_made()
    got = lockstep_records(scenario, seed, sim.positions)
    assert len(got) == len(made.epoch)
    for r in range(len(made.epoch)):
        d = got[(int(made.source[r]), int(made.target[r]), int(made.epoch[r]))]
        assert (d.verdict != "drop") == (made.verdict[r] == "pass")
        if made.queue[r] == AIR:
            assert (d.queue, d.model) == (AIR, made.model[r])
    return list(got.values())


@pytest.mark.parametrize("channel", ["shared", "own"])
def test_netem_lockstep_decides_the_reports_with_the_states_as_the_simulator(
    paper: Scenario, seed: int, channel: str
) -> None:
    got = decided_alike(on_air(paper, 12, reports="with_states", control_channel=channel), seed)
    assert {d.queue for d in got if d.target == LEADER_ENDPOINT} == {AIR}
    assert sum(d.verdict == "drop" for d in got) > 0


@pytest.mark.parametrize(("strategy", "aired"), [("hold", False), ("estimate", True)])
def test_the_estimation_traffic_takes_the_air_only_for_a_strategy_that_uses_it_when_asked(
    paper: Scenario, seed: int, strategy: str, aired: bool
) -> None:
    s = on_air(paper, 6, reports="with_states", estimation_traffic="when_used")
    s = s.with_overrides(strategy={**s.strategy.model_dump(), "name": strategy})
    got = decided_alike(s, seed)
    control = {d.queue for d in got if LEADER_ENDPOINT in (d.source, d.target)}
    assert control == ({AIR} if aired else {None})
    assert {d.queue for d in got if LEADER_ENDPOINT not in (d.source, d.target)} >= {AIR}
