"""The recorder's epochs follow the team (issue 26): one metrics, frames and scene per epoch
with agents out by the scenario's events or lost mid-run, who is out marked."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from analysis import formation_error, shape_error, team_errors
from formation import keys
from formation.codec import encode
from formation.messages import (
    CoordinationState,
    Decision,
    DecisionBatch,
    EpochMetrics,
    LeaderEstimate,
    Status,
)
from formation.scenario import Scenario
from recorder.live.epoch_assembly import CLOSE_AFTER, EpochAssembler
from recorder.live.roster import Roster, team_detail
from recorder.reading.decoder import as_dict, decode_kind

EVENTS = Path(__file__).resolve().parents[3] / "scenarios" / "events.toml"
RUN = "e1"
Out = list[tuple[str, bytes]]


def state(i: int, k: int, x: np.ndarray) -> tuple[str, bytes]:
    msg = CoordinationState(
        run_id=RUN, sender=f"agent/{i}", seq=k, epoch=k, stamp_ns=1, agent=i, position=x.tolist()
    )
    return keys.agent_state(RUN, i), encode(msg)


def estimate(s: Scenario, k: int) -> bytes:
    msg = LeaderEstimate(
        run_id=RUN, sender="leader", seq=k, epoch=k, stamp_ns=1,
        positions=[None] * s.n, covariances=[None] * s.n, observable=[False] * s.n,
        tree=[], healthy=[], components=1, rigidity_rank=7, rigid=True,
        x_ref=[0.0, 0.0], v_ref=[0.0, 0.0], reports_received=s.n,
    )  # fmt: skip
    return encode(msg)


def decisions(s: Scenario, k: int, agents: set[int]) -> bytes:
    """netem's formation decisions of ``k``: one per link between ``agents``, all passed."""
    rows = [
        Decision(source=int(a), target=int(b), link_class="formation", epoch=k, seq=k,
                 verdict="pass")
        for a, b in s.directed_links if a in agents and b in agents
    ]  # fmt: skip
    return encode(
        DecisionBatch.of_rows(run_id=RUN, sender="netem", seq=k, epoch=k, stamp_ns=1, phase="state",
                      decisions=rows)
    )  # fmt: skip


def team_status(down: list[int], back: dict[str, int] | None = None, seq: int = 1) -> bytes:
    """netem's team status, as ``netem.node.team_changed`` writes it."""
    detail = {"event": "x", "epoch": 0, "team": [], "away": [], "down": down, "back": back or {}}
    msg = Status(run_id=RUN, sender="netem", seq=seq, epoch=-1, stamp_ns=1, role="netem",
                 state="running", detail=json.dumps(detail))  # fmt: skip
    return encode(msg)


def of(out: Out, key: str) -> list[bytes]:
    return [p for k, p in out if k == key]


def metrics(out: Out) -> list[EpochMetrics]:
    return [EpochMetrics.model_validate_json(p) for p in of(out, keys.metrics(RUN))]


def scene_meta(payload: bytes) -> dict[str, str]:
    (entity,) = as_dict(decode_kind("scene", payload))["entities"]
    return {m["key"]: m["value"] for m in entity["metadata"]}


def labels(payload: bytes) -> list[str]:
    (entity,) = as_dict(decode_kind("scene", payload))["entities"]
    return [t["text"] for t in entity["texts"]]


def epoch(asm: EpochAssembler, s: Scenario, k: int, x: np.ndarray, agents: list[int]) -> Out:
    """Epoch ``k`` as a lockstep run sends it: the states of ``agents``, then netem's
    decisions between those the plan has present, then the leader's estimate."""
    out: Out = []
    for i in agents:
        out += asm.on_state(*state(i, k, x[i - 1]), stamp_ns=k)
    if k < s.epochs:
        on = set(agents) & set(s.membership.taking_part(k))
        out += asm.on_decision(keys.netem_decision(RUN), decisions(s, k, on), k)
        out += asm.on_estimate(keys.leader_estimate_out(RUN), estimate(s, k), k)
    return out


def test_an_events_run_has_one_of_each_per_epoch_as_it_goes() -> None:
    s = Scenario.from_file(EVENTS)
    published = s.membership.published
    asm = EpochAssembler(s, RUN, clock=lambda: 0)
    rng = np.random.default_rng(2)
    x0 = s.initial_positions()
    seen = np.zeros_like(x0)
    for k in range(s.epochs + 1):
        x = s.offsets + 0.1 * rng.standard_normal(x0.shape)
        agents = [int(i) + 1 for i in np.flatnonzero(published[k])]
        out = epoch(asm, s, k, x, agents)
        # everything of k out before k + 1 starts: the live view never waits for an agent out
        (m,) = metrics(out)
        assert len(of(out, keys.frames(RUN))) == 1 and len(of(out, keys.scene(RUN))) == 1
        out_ids = [i for i in range(1, s.n + 1) if i not in agents]
        assert m.epoch == k and m.out == out_ids
        team = published[k]
        seen[team] = x[team]
        body = np.where(team[:, None], x, np.where(published[:k].any(axis=0)[:, None], seen, x0))
        assert m.positions == body.tolist()  # out: where its body was last seen, or its start
        fe, se = team_errors(body, team, formation_error(body, s.edge_array, s.weights),
                             shape_error(body, s.edge_array, s.offsets), s.edge_array,
                             s.weights, s.offsets)  # fmt: skip
        assert (m.formation_error_m, m.shape_error_m) == (float(fe), float(se))
        (scene,) = of(out, keys.scene(RUN))
        assert scene_meta(scene).get("out", "") == ",".join(map(str, out_ids))
        assert [t.endswith(" out") for t in labels(scene)] == [not p for p in team]
    assert asm.finish(0) == [] and asm.drawn_early == 0 and asm.incomplete == 0


def test_an_agent_lost_mid_run_is_out_once_netem_says_so_and_back_from_its_epoch(
    paper: Scenario,
) -> None:
    asm = EpochAssembler(paper, RUN, clock=lambda: 0)
    x = paper.offsets
    everyone, others = [1, 2, 3, 4, 5], [1, 2, 4, 5]
    out: Out = []
    for k in range(3):
        out += epoch(asm, paper, k, x, everyone)
    for i in others:
        assert asm.on_state(*state(i, 3, x[i - 1]), stamp_ns=3) == [], "3's state may still come"
    out = asm.on_status(keys.status(RUN, "netem", 0), team_status([3]), 3)  # lost agent 3
    assert [m.out for m in metrics(out)] == [[3]]
    out = asm.on_decision(keys.netem_decision(RUN), decisions(paper, 3, set(others)), 3)
    out += asm.on_estimate(keys.leader_estimate_out(RUN), estimate(paper, 3), 3)
    (scene,) = of(out, keys.scene(RUN))
    assert scene_meta(scene) == {"epoch": "3", "out": "3"} and "3 out" in labels(scene)
    for k in range(4, 8):  # netem waits for nobody; neither does the recorder
        out = epoch(asm, paper, k, x, others)
        assert [(m.epoch, m.out) for m in metrics(out)] == [(k, [3])]
    asm.on_status(keys.status(RUN, "netem", 0), team_status([], {"3": 9}, seq=2), 7)
    assert metrics(epoch(asm, paper, 8, x, others))[0].out == [3]
    for i in others:
        assert asm.on_state(*state(i, 9, x[i - 1]), stamp_ns=9) == [], "back from 9: waited for"
    out = asm.on_state(*state(3, 9, x[2]), stamp_ns=9)
    assert [(m.epoch, m.out) for m in metrics(out)] == [(9, [])]
    out = asm.on_decision(keys.netem_decision(RUN), decisions(paper, 9, set(everyone)), 9)
    out += asm.on_estimate(keys.leader_estimate_out(RUN), estimate(paper, 9), 9)
    (scene,) = of(out, keys.scene(RUN))
    assert scene_meta(scene) == {"epoch": "9"}
    assert asm.incomplete == 6 and asm.drawn_early == 0  # epochs 3..8 without agent 3


def test_an_epoch_missing_a_state_closes_once_a_later_one_shows_it_is_over(
    paper: Scenario,
) -> None:
    """Without netem's word (a realtime run's lost packet, a filtered recording)."""
    asm = EpochAssembler(paper, RUN)
    got: Out = []
    for k in range(CLOSE_AFTER + 1):
        for i in (1, 2, 4, 5):
            got += asm.on_state(*state(i, k, paper.offsets[i - 1]), stamp_ns=k)
        if k == 0:
            assert got == []
    assert [m.epoch for m in metrics(got)] == [0]
    est = asm.on_estimate(keys.leader_estimate_out(RUN), estimate(paper, 1), 0)
    assert [(m.epoch, m.out) for m in metrics(est)] == [(1, [3])], "its estimate: it is over"


def test_scenes_do_not_wait_for_estimates_while_the_leader_is_down(paper: Scenario) -> None:
    asm = EpochAssembler(paper, RUN)
    asm.on_status(keys.status(RUN, "netem", 0), team_status([0]), 0)
    out: Out = []
    for k in range(3):
        for i in range(1, paper.n + 1):
            out += asm.on_state(*state(i, k, paper.offsets[i - 1]), stamp_ns=k)
        out += asm.on_decision(keys.netem_decision(RUN), decisions(paper, k, set(range(6))), k)
        assert len(of(out, keys.scene(RUN))) == k + 1
    assert asm.drawn_early == 0


def test_the_same_messages_give_the_same_derived_channels() -> None:
    """A replay of a recording derives what the live recorder did (no clock in the output)."""
    s = Scenario.from_file(EVENTS)

    def run() -> list[tuple[str, Any]]:
        asm = EpochAssembler(s, RUN, clock=lambda: 7)
        out: Out = []
        for k in range(s.epochs + 1):
            agents = [i for i in s.membership.taking_part(k) if i != 2 or k < 20]
            out += epoch(asm, s, k, s.offsets + 0.01 * k, agents)
            if k == 20:
                out += asm.on_status(keys.status(RUN, "netem", 0), team_status([2]), k)
        return [(key, p) for key, p in out + asm.finish(5)]

    first, second = run(), run()
    assert first == second
    assert [m.epoch for m in metrics(first)] == list(range(s.epochs + 1))


def test_the_roster_reads_the_plan_and_netem_team_statuses() -> None:
    s = Scenario.from_file(EVENTS)
    r = Roster(s)
    assert r.expected(0) == {1, 2, 3, 4, 5} and r.expected(15) == {1, 2, 3, 4, 5, 6}
    assert 3 in r.expected(25) and 3 not in r.expected(26)  # a crash's last state is its own
    assert r.expected(s.epochs + 5) == r.expected(s.epochs)
    r.on_team({"down": [4, 0], "back": {}})
    assert 4 not in r.expected(30) and not r.estimated(30)
    r.on_team({"down": [], "back": {"4": 33, "0": 31}})
    assert 4 not in r.expected(32) and 4 in r.expected(33)
    assert not r.estimated(30) and r.estimated(31) and not r.estimated(s.epochs)
    team = np.ones(s.n, dtype=bool)
    assert r.decisions(10, team) == 14  # agent 6 not yet joined: the pentagon's 7 edges
    assert r.decisions(s.epochs, team) == 0


@pytest.mark.parametrize("detail", ["", "lost agent 3", "[1]", '{"down": 3}', '{"event": "x"}'])
def test_other_details_are_not_team_statuses(detail: str) -> None:
    assert team_detail(detail) is None
