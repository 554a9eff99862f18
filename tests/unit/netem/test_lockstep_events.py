"""netem's lockstep core with scenario events (issue 20 item 1), without a network.

Who is out at each epoch comes from the scenario alone, so the drop pattern does not depend
on when a process actually went or came back.
"""

from __future__ import annotations

from collections import Counter

import pytest

from formation.scenario import Scenario
from netem.proxy.lockstep import LockstepCore

from .test_lockstep import lockstep
from .test_lockstep_rejoin import closes


def state(i: int, k: int) -> bytes:
    return b'{"agent":%d,"position":[%d.5,1.0]}' % (i, k)


def epoch_of(core: LockstepCore, k: int, agents: list[int]) -> None:
    """The states and reports of epoch ``k`` of ``agents``, then the leader's estimates (all)."""
    for i in agents:
        core.packet(("state", i, 0), k, k, state(i, k))
    for i in agents:
        core.packet(("report", i, 0), k, k, b"{}")
    for i in core.links.agents:  # the leader sends every agent its part
        core.packet(("estimate", 0, i), k, k, b"{}")


@pytest.mark.parametrize("network", [{}, {"formation_default": [{"model": "bernoulli", "p_loss": 0.3}]}],
                         ids=["clean", "lossy"])  # fmt: skip
def test_crash_restart_and_leave_are_keyed_to_their_epochs(
    paper: Scenario, seed: int, network: dict[str, object]
) -> None:
    events = [{"epoch": 3, "agent": 3, "action": "crash"},
              {"epoch": 6, "agent": 3, "action": "restart"},
              {"epoch": 8, "agent": 5, "action": "leave"}]  # fmt: skip
    scenario = paper.with_overrides(epochs=12, network=network, events=events)
    core, wire = lockstep(scenario, seed)
    team = scenario.membership
    for k in range(3):
        epoch_of(core, k, team.taking_part(k))
    assert core.applied == []
    core.packet(("state", 3, 0), 3, 3, state(3, 3))  # its last state: the body's, kept
    assert core.state_of(3) == (3, state(3, 3)) and 3 in core.away
    core.packet(("state", 3, 0), 3, 3, state(3, 3))  # the same again: applied once
    assert core.applied == [("crash", 3, 3)]  # for the node to announce (a team status)
    assert core.planned_start(3) == 6
    for k in range(3, 6):
        epoch_of(core, k, team.taking_part(k))
    assert closes(wire, "state", 3) == [0, 1, 2], "no delivery to a crashed agent"
    core.sender_died(3)  # its process killed: the liveliness loss changes nothing
    assert core.rejoin(3) == 6 and core.rejoin(3) == 6  # asking twice gives the same epoch
    for k in range(6, 8):
        epoch_of(core, k, team.taking_part(k))
    core.packet(("state", 5, 0), 8, 8, state(5, 8))  # agent 5's goodbye
    assert 5 in core.progress.final_states
    assert core.applied == [("crash", 3, 3), ("restart", 3, 6), ("leave", 5, 8)]
    for k in range(8, scenario.epochs):
        epoch_of(core, k, team.taking_part(k))
    assert not core.finished()
    for i in team.taking_part(scenario.epochs):
        core.packet(("state", i, 0), scenario.epochs, scenario.epochs, b"{}")
    assert core.finished()
    assert closes(wire, "state", 3) == [0, 1, 2, *range(6, 12)]
    assert closes(wire, "estimate", 5) == list(range(8))
    for d in wire.deliveries:
        senders = core.links.senders(d.phase, d.receiver)
        out = {i for i in senders if i and not team.present[d.epoch, i - 1]}
        assert set(d.dead) == out, d
    # One record per packet sent between two agents taking part, and none for the others.
    core.flush()
    rec = Counter((r.link_class, r.source, r.target, r.epoch) for r in wire.decisions)
    assert set(rec.values()) == {1}
    formation = {(s, t, k) for c, s, t, k in rec if c == "formation"}
    expected = {
        (int(a), int(b), k)
        for k in range(scenario.epochs)
        for a, b in scenario.directed_links
        if team.present[k, a - 1] and team.present[k, b - 1]
    }
    assert formation == expected


def test_an_agent_that_joins_is_not_waited_for_before_its_epoch(paper: Scenario, seed: int) -> None:
    events = [{"epoch": 4, "agent": 5, "action": "join"}]
    scenario = paper.with_overrides(epochs=8, events=events)
    core, wire = lockstep(scenario, seed)
    assert 5 in core.away and core.planned_start(5) == 4
    for k in range(4):
        epoch_of(core, k, [1, 2, 3, 4])
    assert closes(wire, "state", 3) == [0, 1, 2, 3] and closes(wire, "state", 5) == []
    assert core.rejoin(5) == 4 and core.applied == [("join", 5, 4)]
    for k in range(4, 8):
        epoch_of(core, k, [1, 2, 3, 4, 5])
    assert closes(wire, "state", 5) == [4, 5, 6, 7]
    for i in [1, 2, 3, 4, 5]:
        core.packet(("state", i, 0), 8, 8, b"{}")
    assert core.finished()
