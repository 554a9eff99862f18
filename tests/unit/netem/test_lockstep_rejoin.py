"""netem's lockstep core when a sender dies and comes back (issue 20), without a network."""

from __future__ import annotations

from collections import Counter

import pytest

from formation.keys import LEADER_ENDPOINT
from formation.scenario import Scenario
from netem.proxy.lockstep import LockstepCore

from .test_lockstep import Wire, lockstep


def epoch_of(core: LockstepCore, k: int, agents: list[int], leader: bool = True) -> None:
    """Every live agent's state and report of epoch ``k``, then the leader's estimates."""
    for i in agents:
        core.packet(("state", i, 0), k, k, b'{"agent":%d,"position":[%d.5,1.0]}' % (i, k))
    for i in agents:
        core.packet(("report", i, 0), k, k, b"{}")
    if leader:
        for i in range(1, core.links.agents[-1] + 1):  # the leader sends every agent its part
            core.packet(("estimate", 0, i), k, k, b"{}")


def closes(wire: Wire, phase: str, receiver: int) -> list[int]:
    return [d.epoch for d in wire.deliveries if (d.phase, d.receiver) == (phase, receiver)]


@pytest.mark.parametrize("network", [{}, {"formation_default": [{"model": "bernoulli", "p_loss": 0.3}]}],
                         ids=["clean", "lossy"])  # fmt: skip
def test_an_agent_back_takes_part_from_the_epoch_netem_gives_it(
    paper: Scenario, seed: int, network: dict[str, object]
) -> None:
    scenario = paper.with_overrides(epochs=12, network=network)
    core, wire = lockstep(scenario, seed)
    everyone, others = [1, 2, 3, 4, 5], [1, 2, 4, 5]
    for k in range(3):
        epoch_of(core, k, everyone)
    core.packet(("state", 3, 0), 3, 3, b'{"agent":3,"position":[7.0,8.0]}')  # then it dies
    core.sender_died(3)
    for k in range(3, 6):
        epoch_of(core, k, others)
    assert core.state_of(3) == (3, b'{"agent":3,"position":[7.0,8.0]}')
    back = core.rejoin(3)
    assert back == 6 and core.rejoin(3) == 6  # asking twice gives the same epoch
    for k in range(back, scenario.epochs):
        epoch_of(core, k, everyone)
    for i in everyone:
        core.packet(("state", i, 0), scenario.epochs, scenario.epochs, b"{}")
    assert core.finished()
    assert closes(wire, "state", 3) == [0, 1, 2, *range(back, scenario.epochs)]
    assert closes(wire, "estimate", 3) == [0, 1, 2, *range(back, scenario.epochs)]
    for i in others:
        assert closes(wire, "state", i) == list(range(scenario.epochs))
    for d in wire.deliveries:  # dead while down, waited for again from the epoch it was given
        hears_3 = 3 in core.links.senders(d.phase, d.receiver)
        assert (3 in d.dead) == (hears_3 and 3 <= d.epoch < back), d
    core.flush()
    rec = Counter((r.link_class, r.source, r.target, r.epoch) for r in wire.decisions)
    assert set(rec.values()) == {1}
    assert {e for _, e in wire.early} <= set(range(3, back))  # four receivers closed those


def test_the_leader_down_its_estimates_close_empty_and_it_resumes(
    paper: Scenario, seed: int
) -> None:
    scenario = paper.with_overrides(epochs=10)
    core, wire = lockstep(scenario, seed)
    everyone = [1, 2, 3, 4, 5]
    for k in range(2):
        epoch_of(core, k, everyone)
    core.sender_died(LEADER_ENDPOINT)
    for k in range(2, 5):  # agents go on: each estimate epoch closes once its report came
        epoch_of(core, k, everyone, leader=False)
        assert all(closes(wire, "estimate", i)[-1] == k for i in everyone)
    assert core.progress.estimates_done == 5
    back = core.rejoin(LEADER_ENDPOINT)
    assert back == 5
    for k in range(back, scenario.epochs):
        epoch_of(core, k, everyone)
    for i in everyone:
        core.packet(("state", i, 0), scenario.epochs, scenario.epochs, b"{}")
    assert core.finished()
    for d in wire.deliveries:
        if d.phase == "estimate":
            assert (d.dead == [LEADER_ENDPOINT]) == (2 <= d.epoch < back), d
            assert len(d.packets) == (0 if 2 <= d.epoch < back else 1)
    for i in everyone:
        assert closes(wire, "estimate", i) == list(range(scenario.epochs))
