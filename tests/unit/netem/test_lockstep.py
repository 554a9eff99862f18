"""netem's lockstep core without a network: packets and deaths in, deliveries and records out.

The outbox encodes what the node would publish and parses it back as a receiver and
the recorder do, so the tests read the same messages as the integration tests.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np
import pytest

from formation.scenario import Scenario
from netem.proxy.lockstep import LockstepCore
from netem.proxy.progress import Progress
from netem.proxy.records import Ledger
from netem.proxy.routes import Links, Route
from testkit.lockstep_wire import Wire, receivers


def lockstep(scenario: Scenario, seed: int) -> tuple[LockstepCore, Wire]:
    links, wire = Links(scenario, seed), Wire(receivers(scenario))
    core = LockstepCore(links, scenario.epochs, Progress(links.agents, scenario.epochs, lambda: None),
                    Ledger(), wire)  # fmt: skip
    return core, wire


def state(i: int, k: int) -> tuple[Route, int, int, bytes]:
    return ("state", i, 0), k, k, b'{"agent":%d,"epoch":%d}' % (i, k)


@pytest.mark.parametrize(
    "network", [{}, {"formation_default": [{"model": "bernoulli", "p_loss": 0.3}]}],
    ids=["clean", "lossy"],
)  # fmt: skip
def test_a_sender_dying_mid_epoch_closes_every_receiver_once(
    paper: Scenario, seed: int, network: dict[str, Any]
) -> None:
    scenario = paper.with_overrides(epochs=10, network=network)
    core, wire = lockstep(scenario, seed)
    senders = scenario.in_neighbours  # paper: 5 hears 3 and 4 only
    for i in (3, 4, 1, 2):  # agent 5's packet of epoch 0 never comes
        core.packet(*state(i, 0))
    early = sorted(d.receiver for d in wire.deliveries)
    assert early == [r for r in range(1, 6) if 5 not in senders[r - 1]]  # their senders all came
    core.sender_died(5)
    by_receiver = Counter(d.receiver for d in wire.deliveries)
    assert by_receiver == dict.fromkeys(range(1, 6), 1), by_receiver
    assert not core.open  # nothing of epoch 0 waits for a close that will not come
    for d in wire.deliveries:
        want = [j for j in senders[d.receiver - 1] if j != 5]
        assert (d.phase, d.epoch) == ("state", 0)
        assert sorted([p.source for p in d.packets] + d.lost) == want
        assert d.dead == ([5] if 5 in senders[d.receiver - 1] else [])
    # One record per packet that came: every out-link of agents 1-4, exactly once.
    core.flush()
    rec = Counter((r.source, r.target) for r in wire.decisions)
    want_links = {(int(a), int(b)) for a, b in scenario.directed_links if int(a) != 5}
    assert set(rec) == want_links and set(rec.values()) == {1}


def test_a_delayed_packet_due_in_an_epoch_where_all_pass_goes_out_with_its_delivery(
    paper: Scenario, seed: int
) -> None:
    delay = {"model": "delay", "epochs": 0, "jitter_epochs": 1}
    network = {"links": [{"between": [3, 5], "direction": "forward", "models": [delay]}]}
    scenario = paper.with_overrides(epochs=60, network=network)
    core, wire = lockstep(scenario, seed)
    late = core.links.models[("formation", 3, 5)]
    k = next(
        k for k in range(scenario.epochs - 1)
        if late.decide(k).delay_epochs == 1
        and all(m.decide(k + 1).verdict == "pass" for m in core.links.models.values())
    )  # fmt: skip
    for epoch in range(k + 2):
        for i in range(1, 6):
            core.packet(*state(i, epoch))
    closes = Counter((d.receiver, d.epoch) for d in wire.deliveries)
    assert closes == {(r, e): 1 for r in range(1, 6) for e in range(k + 2)}
    into_5 = {d.epoch: d for d in wire.deliveries if d.receiver == 5}
    assert 3 in into_5[k].lost and 3 not in [p.source for p in into_5[k].packets]
    got = sorted((p.source, p.sent_epoch) for p in into_5[k + 1].packets)
    assert got == [(3, k), (3, k + 1), (4, k + 1)] and into_5[k + 1].lost == []
    assert not core.delayed
    core.flush()
    rec = Counter((r.source, r.target, r.epoch) for r in wire.decisions if r.epoch >= k)
    assert set(rec.values()) == {1} and len(rec) == 2 * len(scenario.directed_links)


def test_every_receiver_closes_once_per_phase_and_epoch_under_random_loss(
    paper: Scenario, seed: int
) -> None:
    lossy = {"model": "bernoulli", "p_loss": 0.04}
    network = {
        "formation_default": [lossy],
        "control_default": [lossy],
        "links": [
            {"between": [3, 5], "direction": "forward",
             "models": [lossy, {"model": "delay", "epochs": 0, "jitter_epochs": 1}]},
            {"between": [1, 3], "direction": "forward",
             "models": [lossy, {"model": "duplicate", "p": 0.2}]},
        ],
    }  # fmt: skip
    scenario = paper.with_overrides(epochs=80, network=network)
    core, wire = lockstep(scenario, seed)
    rng = np.random.default_rng(seed)
    agents = list(range(1, scenario.n + 1))
    for k in range(scenario.epochs):  # an epoch's states and reports in any order, then estimates
        first: list[Route] = [("state", i, 0) for i in agents] + [("report", i, 0) for i in agents]
        for n in rng.permutation(len(first)):
            core.packet(first[n], k, k, b"{}")
        for i in rng.permutation(agents):
            core.packet(("estimate", 0, int(i)), k, k, b"{}")
    for i in agents:
        core.packet(*state(i, scenario.epochs))  # final states
    assert core.finished()
    epochs = list(range(scenario.epochs))
    closes = Counter((d.phase, d.receiver, d.epoch) for d in wire.deliveries)
    assert closes == {
        (ph, r, e): 1 for ph, rs in wire.receivers.items() for r in rs for e in epochs
    }
    for phase, closers in wire.receivers.items():
        for r in closers:  # in epoch order
            assert [
                d.epoch for d in wire.deliveries if (d.phase, d.receiver) == (phase, r)
            ] == epochs
    for d in wire.deliveries:
        now = [p.source for p in d.packets if p.sent_epoch == d.epoch]
        if d.phase == "estimate":
            assert now + d.lost == [0]
        else:
            assert sorted(now + d.lost) == sorted(core.links.senders(d.phase, d.receiver))
    # One record per packet, each published once its epoch was closed everywhere.
    core.flush()
    rec = Counter((r.link_class, r.source, r.target, r.epoch) for r in wire.decisions)
    assert set(rec.values()) == {1}
    assert len(rec) == (len(scenario.directed_links) + 2 * scenario.n) * scenario.epochs
    assert not wire.early
    # Delayed and duplicated packets went out.
    assert any(p.sent_epoch < d.epoch for d in wire.deliveries for p in d.packets)
    assert any(p.copies == 2 for d in wire.deliveries for p in d.packets)
