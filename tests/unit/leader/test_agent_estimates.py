"""Each agent gets its in-neighbours' part of the leader's estimate, and nothing else; the
whole estimate is a valid message with every field."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import orjson

from formation import keys
from formation.messages import AgentEstimate, LeaderEstimate
from formation.scenario import Scenario
from leader.epoch import LeaderEpoch, leader_epoch
from leader.node import LeaderNode
from leader.wire import EstimateParts, estimate_message, position_rows
from shell import MemoryBus, Service
from testbed.sim.team_generators import henneberg_team

ROOT = Path(__file__).resolve().parents[3]


HEAD = {"run_id": "r", "sender": "leader", "seq": 0, "epoch": 4, "stamp_ns": 1}


def _exact_measurements(scenario: Scenario) -> tuple[np.ndarray, np.ndarray]:
    links = scenario.directed_links
    x = scenario.offsets
    z = x[links[:, 1] - 1] - x[links[:, 0] - 1]
    known = np.ones(len(links), dtype=bool)
    return known, z


def test_every_agent_gets_its_in_neighbours_estimates() -> None:
    for scenario in (Scenario.from_file(ROOT / "scenarios/paper.toml"), henneberg_team(30)):
        known, z = _exact_measurements(scenario)
        cut = scenario.directed_links[:, 1] == scenario.n  # the last agent: unobservable
        cut |= scenario.directed_links[:, 0] == scenario.n
        x_ref = scenario.offsets[scenario.reference_agent - 1]
        lead = leader_epoch(scenario, known & ~cut, z, x_ref)
        res = lead.estimate
        service = Service(MemoryBus(), "run-1", "leader", 0)
        parts = EstimateParts(scenario.in_neighbours, service.header_format())
        texts = parts.texts(position_rows(res.positions, res.observable), [0.1, 0.2], 4, 99, 7)
        got = [AgentEstimate.model_validate_json(t) for t in texts]
        links = scenario.directed_links
        for i, est in enumerate(got, start=1):
            assert (est.run_id, est.sender, est.seq, est.epoch, est.stamp_ns) == (
                "run-1", "leader", 7, 4, 99,
            )  # fmt: skip
            assert est.agent == i and est.v_ref == [0.1, 0.2]
            assert est.neighbours == sorted(int(j) for j, r in links if r == i)
            for j, p in zip(est.neighbours, est.positions, strict=True):
                ok = bool(res.observable[j - 1])
                assert p == (res.positions[j - 1].tolist() if ok else None)  # the same floats
        assert any(None in est.positions for est in got)


def test_the_bundle_is_what_orjson_writes_of_the_parts_each_escaped_there() -> None:
    """The parts are joined into the bundle already escaped: the bytes orjson writes of the
    bundle's fields, with a run id that needs escaping in a part and again in the bundle."""
    scenario = henneberg_team(30)
    known, z = _exact_measurements(scenario)
    cut = scenario.directed_links[:, 1] == scenario.n  # an unobservable agent: null
    cut |= scenario.directed_links[:, 0] == scenario.n
    lead = leader_epoch(scenario, known & ~cut, z, scenario.offsets[scenario.reference_agent - 1])
    service = Service(MemoryBus(), 'run "1" \\ é %d', "leader", 0)
    parts = EstimateParts(scenario.in_neighbours, service.header_format())
    rows = position_rows(lead.estimate.positions, lead.estimate.observable)
    texts = parts.texts(rows, [0.1, -2e-7], 4, 99, 3)
    head = {**HEAD, "run_id": service.run_id}
    bundle = parts.bundle(head, rows, [0.1, -2e-7], 4, 99, 3)
    fields = [{"agent": i, "seq": 3, "message": t.decode()} for i, t in enumerate(texts, start=1)]
    assert bundle == orjson.dumps({**head, "kind": "bundle", "phase": "estimate", "parts": fields})
    assert AgentEstimate.model_validate_json(texts[0]).run_id == service.run_id
    assert b"null" in b"".join(texts)


def test_position_rows_are_orjsons_text_of_each_row(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for n, d in ((1, 2), (7, 1), (40, 2), (40, 3)):
        positions = rng.standard_normal((n, d)) * 10.0 ** rng.integers(-20, 20, (n, d))
        positions[0, 0] = -0.0
        observable = rng.random(n) < 0.8
        for x in (positions, positions[:, ::-1]):  # the array and a strided view of it
            rows = zip(x.tolist(), observable.tolist(), strict=True)
            want = [orjson.dumps(p) if ok else b"null" for p, ok in rows]
            assert position_rows(x, observable) == want


def test_whole_estimate_is_a_valid_message_with_every_field() -> None:
    scenario = henneberg_team(30)
    known, z = _exact_measurements(scenario)
    cut = scenario.directed_links[:, 1] == scenario.n  # the last agent hears nobody: unobservable
    cut |= scenario.directed_links[:, 0] == scenario.n
    lead = leader_epoch(scenario, known & ~cut, z, scenario.offsets[scenario.reference_agent - 1])
    assert not lead.estimate.observable.all()
    raw = estimate_message(HEAD, lead, [1.0, 2.0], [0.1, 0.2], scenario.edge_array, 29)
    _check_estimate(LeaderEstimate.model_validate_json(raw), lead, scenario)


def test_an_estimate_of_every_agent_carries_every_block() -> None:
    scenario = henneberg_team(30)
    known, z = _exact_measurements(scenario)
    lead = leader_epoch(scenario, known, z, scenario.offsets[scenario.reference_agent - 1])
    assert lead.estimate.observable.all()
    raw = estimate_message(HEAD, lead, [1.0, 2.0], [0.1, 0.2], scenario.edge_array, 29)
    _check_estimate(LeaderEstimate.model_validate_json(raw), lead, scenario)


def _check_estimate(msg: LeaderEstimate, lead: LeaderEpoch, scenario: Scenario) -> None:
    res = lead.estimate
    assert res.covariances is not None
    for i in range(scenario.n):
        ok = bool(res.observable[i])
        assert msg.observable[i] == ok
        assert msg.positions[i] == (res.positions[i].tolist() if ok else None)
        assert msg.covariances[i] == (res.covariances[i].tolist() if ok else None)
    edges = scenario.edge_array
    assert msg.tree == [tuple(e) for e in edges[lead.tree].tolist()]
    assert msg.healthy == [tuple(e) for e in edges[lead.healthy].tolist()]
    assert (msg.components, msg.rigidity_rank, msg.rigid) == (
        lead.components, lead.rigidity_rank, lead.rigid,
    )  # fmt: skip
    assert (msg.x_ref, msg.v_ref, msg.reports_received, msg.epoch) == (
        [1.0, 2.0],
        [0.1, 0.2],
        29,
        4,
    )


def test_realtime_sends_each_part_on_its_agents_key_and_no_bundle() -> None:
    scenario = Scenario.from_file(ROOT / "scenarios/paper.toml").with_overrides(
        runtime={"mode": "realtime", "realtime_period_s": 0.05}
    )
    bus = MemoryBus()
    node = LeaderNode(Service(bus, "run-2", "leader", 0), scenario)
    got: dict[int, list[AgentEstimate]] = {i: [] for i in range(1, scenario.n + 1)}
    for i in got:
        bus.declare_subscriber(
            keys.leader_estimate_for("run-2", i),
            lambda s, mine=got[i]: mine.append(
                AgentEstimate.model_validate_json(s.payload.to_bytes())
            ),
        )
    known, z = _exact_measurements(scenario)
    lead = leader_epoch(scenario, known, z, scenario.offsets[scenario.reference_agent - 1])
    res = lead.estimate
    for k in (0, 1):
        node._send_parts(k, position_rows(res.positions, res.observable), [0.1, 0.2])
    assert bus.puts[keys.leader_estimates("run-2")] == 0
    for i, parts in got.items():
        assert [(p.agent, p.epoch, p.seq) for p in parts] == [(i, 0, 0), (i, 1, 1)]
