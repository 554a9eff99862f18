"""netem's lockstep with capacity queues, without a network: a phase's packets are judged
together once all are in, whatever order they came in, and deaths do not hold a phase."""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np

from formation.capacity import Capacity
from formation.scenario import Scenario
from netem.links.capacity import REASONS
from netem.links.capacity_plan import capacity_plan
from netem.proxy.lockstep import LockstepCore
from netem.proxy.progress import Progress
from netem.proxy.records import Ledger
from netem.proxy.routes import Links, Route
from testkit.lockstep_wire import Wire, receivers

CAPACITY: list[dict[str, Any]] = [
    {"scope": "medium", "medium": "ap", "links": "control", "rate_bps": 25_000.0,
     "limit_packets": 4},
    {"scope": "radio", "agent": 3, "rate_bps": 30_000.0, "limit_packets": 2, "policy": "oldest"},
    {"scope": "link", "link": [2, 4], "rate_bps": 9_000.0, "burst_bytes": 400},
    # links alone in their queues, judged as they come: a state of 256 B takes 1.02 s (a
    # backlog, late and full), 0.19 s (in time, by the closed form), 0.205 s (late, by it)
    {"scope": "link", "link": [1, 3], "rate_bps": 2_000.0, "limit_packets": 2},
    {"scope": "link", "link": [4, 1], "rate_bps": 11_000.0},
    {"scope": "link", "link": [5, 4], "rate_bps": 10_000.0},
]  # fmt: skip


def constrained(paper: Scenario, epochs: int) -> Scenario:
    lossy = {"model": "bernoulli", "p_loss": 0.1}
    network = {"formation_default": [lossy], "control_default": [lossy], "capacity": CAPACITY}
    return paper.with_overrides(epochs=epochs, network=network)


def lockstep(scenario: Scenario, seed: int) -> tuple[LockstepCore, Wire]:
    links, wire = Links(scenario, seed), Wire(receivers(scenario))
    core = LockstepCore(links, scenario.epochs, Progress(links.agents, scenario.epochs, lambda: None),
                    Ledger(), wire)  # fmt: skip
    return core, wire


def test_any_arrival_order_gives_the_simulators_queue_verdicts(paper: Scenario, seed: int) -> None:
    scenario = constrained(paper, 40)
    core, wire = lockstep(scenario, seed)
    rng = np.random.default_rng(seed)
    agents = list(range(1, scenario.n + 1))
    for k in range(scenario.epochs):
        first: list[Route] = [("state", i, 0) for i in agents] + [("report", i, 0) for i in agents]
        for n in rng.permutation(len(first)):
            core.packet(first[n], k, k, b"{}")
        for i in rng.permutation(agents):
            core.packet(("estimate", 0, int(i)), k, k, b"{}")
    closes = Counter((d.phase, d.receiver, d.epoch) for d in wire.deliveries)
    assert set(closes.values()) == {1}
    assert len(closes) == sum(len(r) for r in wire.receivers.values()) * scenario.epochs
    assert not wire.early
    # the queues' verdicts are those of the plan the simulator draws, packet for packet
    links = np.concatenate(
        [scenario.directed_links, [[i, 0] for i in agents], [[0, i] for i in agents]]
    )
    models = core.links.models
    cls = ["formation"] * len(scenario.directed_links) + ["report"] * 5 + ["estimate"] * 5
    passed = np.array(
        [[models[(c, int(a), int(b))].decide(k).delivered for c, (a, b) in zip(cls, links, strict=True)]
         for k in range(scenario.epochs)]
    )  # fmt: skip
    codes = capacity_plan(scenario, passed, links)
    got = {(d.source, d.target, d.epoch): d for d in wire.decisions}
    queues = core.links.capacity
    assert queues is not None
    assert len(got) == passed.size
    for k in range(scenario.epochs):
        for c, (a, b) in enumerate(links.tolist()):
            d = got[(a, b, k)]
            want = REASONS[codes[k, c]] if passed[k, c] else None
            if want is None:
                assert d.verdict == "drop" and d.model == "bernoulli"
            elif want:
                assert (d.verdict, d.model) == ("drop", want), (a, b, k)
            else:
                assert d.verdict == "pass"
                assert (d.queue is not None) == queues.constrained((a, b))
    reasons = Counter(d.model for d in wire.decisions if d.verdict == "drop")
    assert reasons["queue_full"] and reasons["queue_late"] and reasons["bernoulli"]


def test_a_sender_dying_mid_phase_does_not_hold_its_queues(paper: Scenario, seed: int) -> None:
    scenario = constrained(paper, 6)
    core, wire = lockstep(scenario, seed)
    for i in (1, 2, 4):  # agent 3's state of epoch 0 never comes, nor 5's
        core.packet(("state", i, 0), 0, 0, b"{}")
    core.packet(("state", 5, 0), 0, 0, b"{}")
    held = {d.receiver for d in wire.deliveries}
    assert held <= {r for r in range(1, 6) if 3 not in core.links.in_links[r]}
    core.sender_died(3)
    closes = Counter((d.phase, d.receiver) for d in wire.deliveries if d.epoch == 0)
    assert closes == {("state", r): 1 for r in range(1, 6)}  # its own too, as without queues
    for d in wire.deliveries:
        if 3 in core.links.in_links[d.receiver]:
            assert d.dead == [3]
    assert not core.queued  # judged, nothing left waiting


def test_queues_in_closed_form_and_a_change_decide_alike_in_any_arrival_order(
    paper: Scenario, seed: int
) -> None:
    # a queue on every link: the states' in time by their closed form; 2's estimates late by
    # it, 3's reports without one (more than half a period); 4 -> 1 becomes a bucket mid-run
    lossy = [{"model": "bernoulli", "p_loss": 0.05}]
    rates = {(4, 1): 11_000.0, (0, 2): 9_000.0, (3, 0): 5_000.0}
    control = [[i, 0] for i in range(1, 6)] + [[0, i] for i in range(1, 6)]
    queues = [
        {"scope": "link", "link": [a, b], "rate_bps": rates.get((a, b), 1e9)}
        for a, b in paper.directed_links.tolist() + control
    ]
    network = {"formation_default": lossy, "control_default": lossy, "capacity": queues}
    scenario = paper.with_overrides(epochs=60, network=network)
    tbf = Capacity.model_validate(
        {"scope": "link", "link": [4, 1], "rate_bps": 1_000.0, "burst_bytes": 300}
    )
    got, change_at = {}, 31
    for shuffled in (True, False):
        rng = np.random.default_rng(seed)
        links, wire = Links(scenario, seed), Wire(receivers(scenario))
        core = LockstepCore(links, scenario.epochs, Progress(links.agents, scenario.epochs,
                        lambda: None), Ledger(), wire)  # fmt: skip
        for k in range(scenario.epochs):
            if k == change_at:  # 4 -> 1 becomes a bucket: its clock is the last packet's
                assert core.links.capacity is not None
                core.links.capacity.change(tbf, from_epoch=k)
                core.models_changed()
            for phase in ("state", "report", "estimate"):
                agents = rng.permutation(scenario.n) + 1 if shuffled else range(1, scenario.n + 1)
                for i in agents:
                    route = ("estimate", 0, int(i)) if phase == "estimate" else (phase, int(i), 0)
                    core.packet(route, k, k, b"{}")  # type: ignore[arg-type]
            core.flush()
        got[shuffled] = (
            sorted(d.model_dump_json() for d in wire.decisions),
            sorted(  # a delivery's packets in the order they came
                d.model_copy(
                    update={"packets": sorted(d.packets, key=lambda p: p.source)}
                ).model_dump_json()
                for d in wire.deliveries
            ),
        )
        reasons = Counter(d.model for d in wire.decisions if d.verdict == "drop")
        assert reasons["queue_late"] and reasons["bernoulli"]
    assert got[True] == got[False]
