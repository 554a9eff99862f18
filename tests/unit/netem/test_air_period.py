"""The reports in the states' contention period (``network.air.reports = "with_states"``), on
the states' channel or on one of their own: what it changes, and netem's lockstep deciding it
as the simulator does."""

from __future__ import annotations

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


@pytest.mark.parametrize("channel", ["shared", "own"])
def test_netem_lockstep_decides_the_reports_with_the_states_as_the_simulator(
    paper: Scenario, seed: int, channel: str
) -> None:
    scenario = on_air(paper, 12, reports="with_states", control_channel=channel)
    sim = testbed.simulate(scenario, seed=seed)
    made = sim.decisions_made()
    got = lockstep_records(scenario, seed, sim.positions)
    assert len(got) == len(made.epoch)
    for r in range(len(made.epoch)):
        d = got[(int(made.source[r]), int(made.target[r]), int(made.epoch[r]))]
        assert (d.verdict != "drop") == (made.verdict[r] == "pass")
        if made.queue[r] == AIR:
            assert (d.queue, d.model) == (AIR, made.model[r])
    reports = [d for d in got.values() if d.target == LEADER_ENDPOINT]
    assert {d.queue for d in reports} == {AIR}
    assert sum(d.verdict == "drop" for d in got.values()) > 0
