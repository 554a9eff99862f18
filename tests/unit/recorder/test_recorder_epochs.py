"""The recorder's per-epoch derivations: metrics and frames when all states are in, the scene
with health (protobuf, decoded by the SDK's schema), log lines from statuses."""

from __future__ import annotations

from typing import Any

import numpy as np

from analysis import formation_error, shape_error
from formation import keys
from formation.codec import encode
from formation.messages import (
    CoordinationState,
    Decision,
    DecisionBatch,
    EpochMetrics,
    LeaderEstimate,
    LinkChange,
    Status,
)
from formation.scenario import Scenario
from recorder.live.epoch_assembly import CLOSE_AFTER, WAIT_EPOCHS, EpochAssembler
from recorder.reading.decoder import as_dict, decode_kind

RUN = "e1"


def decoded_scene(payload: bytes) -> dict[str, Any]:
    """A recorded scene as plain data (it must decode as the SDK's protobuf SceneUpdate)."""
    return as_dict(decode_kind("scene", payload))


def state(i: int, k: int, x: np.ndarray) -> tuple[str, bytes]:
    msg = CoordinationState(
        run_id=RUN, sender=f"agent/{i}", seq=k, epoch=k, stamp_ns=1, agent=i, position=x.tolist()
    )
    return keys.agent_state(RUN, i), encode(msg)


def estimate(
    s: Scenario, k: int, healthy: list[tuple[int, int]], tree: list[tuple[int, int]]
) -> bytes:
    msg = LeaderEstimate(
        run_id=RUN, sender="leader", seq=k, epoch=k, stamp_ns=1,
        positions=[None] * s.n, covariances=[None] * s.n, observable=[False] * s.n,
        tree=tree, healthy=healthy, components=1, rigidity_rank=7, rigid=True,
        x_ref=[0.0, 0.0], v_ref=[0.0, 0.0], reports_received=s.n,
    )  # fmt: skip
    return encode(msg)


def feed_epoch(asm: EpochAssembler, k: int, x: np.ndarray) -> list[tuple[str, bytes]]:
    out = []
    for i in range(1, x.shape[0] + 1):
        out += asm.on_state(*state(i, k, x[i - 1]), stamp_ns=k)
    return out


def test_metrics_when_all_states_are_in(paper: Scenario) -> None:
    asm = EpochAssembler(paper, RUN, clock=lambda: 42)
    rng = np.random.default_rng(1)
    x = paper.offsets + 0.05 * rng.standard_normal(paper.offsets.shape)
    out = []
    for i in range(1, paper.n):
        out += asm.on_state(*state(i, 0, x[i - 1]), stamp_ns=0)
    assert out == []
    out = asm.on_state(*state(paper.n, 0, x[-1]), stamp_ns=0)
    assert [key for key, _ in out] == [keys.metrics(RUN), keys.frames(RUN)]
    m = EpochMetrics.model_validate_json(out[0][1])
    assert m.epoch == 0 and m.stamp_ns == 42 and m.sender == "recorder"
    assert m.formation_error_m == float(formation_error(x, paper.edge_array, paper.weights))
    assert m.shape_error_m == float(shape_error(x, paper.edge_array, paper.offsets))
    assert m.positions == x.tolist()
    tf = as_dict(decode_kind("tf", out[1][1]))["transforms"]
    assert [t["child_frame_id"] for t in tf] == [f"agent{i}" for i in range(1, paper.n + 1)]
    assert {t["parent_frame_id"] for t in tf} == {"world"}
    assert [[t["translation"]["x"], t["translation"]["y"]] for t in tf] == x.tolist()
    assert {t["translation"]["z"] for t in tf} == {0.0}


def decisions(s: Scenario, epochs: list[int], lost: set[tuple[int, int]]) -> bytes:
    """netem's formation decisions of ``epochs`` in one batch (as a clean-epoch flush sends them)."""
    rows = [
        Decision(source=int(a), target=int(b), link_class="formation", epoch=k, seq=k,
                 verdict="drop" if (int(a), int(b)) in lost else "pass")
        for k in epochs for a, b in s.directed_links
    ]  # fmt: skip
    return encode(
        DecisionBatch.of_rows(run_id=RUN, sender="netem", seq=0, epoch=epochs[-1], stamp_ns=1,
                      phase="state", decisions=rows)
    )  # fmt: skip


HEALTHY_EDGES = [(1, 3), (2, 3), (2, 4), (1, 4), (3, 5), (4, 5)]  # 1-2 down


def test_scene_waits_for_the_estimate_and_the_decisions_of_its_epoch(paper: Scenario) -> None:
    asm = EpochAssembler(paper, RUN)
    assert [key for key, _ in feed_epoch(asm, 0, paper.offsets)] == [
        keys.metrics(RUN),
        keys.frames(RUN),
    ]
    est = estimate(paper, 0, HEALTHY_EDGES, [(1, 3), (1, 4)])
    assert asm.on_estimate(keys.leader_estimate_out(RUN), est, 5) == []  # decisions not in
    out = asm.on_decision(keys.netem_decision(RUN), decisions(paper, [0], {(1, 2), (2, 1)}), 6)
    assert [key for key, _ in out] == [keys.scene(RUN)]
    scene = decoded_scene(out[0][1])
    lines = scene["entities"][0]["lines"]
    colors = {(ln["color"]["r"], ln["color"]["g"], ln["thickness"]): len(ln["points"]) // 2
              for ln in lines}  # fmt: skip
    assert colors[(0.84, 0.15, 2.0)] == 1  # the broken edge 1-2
    assert colors[(1.0, 0.84, 4.0)] == 2  # tree edges
    assert colors[(0.84, 0.15, 3.0)] == 2  # lost packets 1->2 and 2->1, half an edge each
    assert asm.drawn_early == 0


def scenes_of(paper: Scenario, order: list[str]) -> list[dict]:
    """Four epochs fed in ``order`` ("s<k>" states, "e<k>" estimate, "d" all decisions)."""
    asm = EpochAssembler(paper, RUN, clock=lambda: 0)
    rng = np.random.default_rng(3)
    xs = [paper.offsets + 0.01 * rng.standard_normal(paper.offsets.shape) for _ in range(4)]
    out: list[tuple[str, bytes]] = []
    for step in order:
        if step[0] == "s":
            out += feed_epoch(asm, int(step[1]), xs[int(step[1])])
        elif step[0] == "e":
            est = estimate(paper, int(step[1]), HEALTHY_EDGES, [(1, 3)])
            out += asm.on_estimate(keys.leader_estimate_out(RUN), est, 0)
        else:
            out += asm.on_decision(
                keys.netem_decision(RUN), decisions(paper, [0, 1, 2, 3], set()), 0
            )
    out += asm.finish(0)
    return [decoded_scene(p) for key, p in out if key == keys.scene(RUN)]


def test_the_same_epochs_give_the_same_scenes_whatever_the_arrival(paper: Scenario) -> None:
    """The decisions of closed epochs come in a batch, late: the scenes wait and keep their order."""
    steps = ["s0", "e0", "s1", "e1", "s2", "e2", "s3", "e3"]
    in_time = scenes_of(paper, ["s0", "e0", "d", "s1", "e1", "s2", "e2", "s3", "e3"])
    late = scenes_of(paper, [*steps, "d"])
    mixed = scenes_of(paper, ["s0", "s1", "e1", "s2", "d", "e0", "s3", "e2", "e3"])
    assert in_time == late == mixed
    assert [sc["entities"][0]["metadata"][0]["value"] for sc in late] == ["0", "1", "2", "3"]
    assert all(ln["color"]["r"] != 0.6 for sc in late for ln in sc["entities"][0]["lines"])


def test_a_scene_missing_parts_is_drawn_late_or_at_the_end(paper: Scenario) -> None:
    paper = paper.with_overrides(epochs=1000)
    asm = EpochAssembler(paper, RUN)
    out = []
    for k in range(WAIT_EPOCHS + 2):  # no estimate, no decisions ever
        out += feed_epoch(asm, k, paper.offsets)
    scenes = [decoded_scene(p) for key, p in out if key == keys.scene(RUN)]
    assert [sc["entities"][0]["metadata"][0]["value"] for sc in scenes] == ["0"]
    final = asm.finish(9)
    assert len(final) == WAIT_EPOCHS + 1 and asm.finish(9) == []
    assert asm.drawn_early == WAIT_EPOCHS + 2


def test_malformed_states_are_counted_and_an_epoch_missing_one_closes_later(
    paper: Scenario,
) -> None:
    asm = EpochAssembler(paper, RUN)
    assert asm.on_state(keys.agent_state(RUN, 1), b"{not json", 0) == []
    assert asm.gate.skipped.by_channel()[keys.agent_state(RUN, 1)] == 1
    asm.on_state(*state(1, 0, paper.offsets[0]), stamp_ns=0)  # epoch 0 never completes
    out = []
    for k in range(1, CLOSE_AFTER + 1):
        out += feed_epoch(asm, k, paper.offsets)
    metrics = [EpochMetrics.model_validate_json(p) for key, p in out if key == keys.metrics(RUN)]
    assert [(m.epoch, m.out) for m in metrics] == [(0, [2, 3, 4, 5]), (1, []), (2, [])]
    assert asm.incomplete == 1 and asm.late == 0
    asm.on_state(*state(2, 0, paper.offsets[1]), stamp_ns=0)
    assert asm.late == 1  # too late to be drawn; the recording holds it


def _status(state: str, detail: str = "", malformed: dict[str, int] | None = None) -> bytes:
    msg = Status(
        run_id=RUN, sender="netem", seq=0, epoch=3, stamp_ns=1, role="netem", state=state,
        detail=detail, malformed=malformed or {},
    )  # fmt: skip
    return encode(msg)


def test_statuses_that_say_something_and_link_changes_are_log_lines(paper: Scenario) -> None:
    asm = EpochAssembler(paper, RUN)
    key = keys.status(RUN, "netem", 0)
    assert asm.on("status", key, _status("running"), 5) == []  # bare progress
    team = '{"event": "lost agent 3", "epoch": 3}'
    got = [
        *asm.on("status", key, _status("running", team), 5_000_000_007),
        *asm.on("status", key, _status("done", "", {"x": 2}), 6),
        *asm.on("status", key, _status("error", "boom"), 7),
        *asm.on("status", keys.status(RUN, "agent", 1), _status("running", "forged"), 8),
    ]
    change = LinkChange(
        run_id=RUN, sender="netem", seq=0, epoch=-1, stamp_ns=1, source=1, target=2,
        link_class="formation", models=[{"kind": "bernoulli", "p_drop": 0.5}], from_epoch=9,
    )  # fmt: skip
    got += asm.on("link_change", keys.netem_change(RUN), encode(change), 9)
    assert {k for k, _ in got} == {keys.log(RUN)}
    lines = [as_dict(decode_kind("log", p)) for _, p in got]
    assert [(ln["level"], ln["name"]) for ln in lines] == [
        ("INFO", "netem"), ("WARNING", "netem"), ("ERROR", "netem"), ("INFO", "netem"),
    ]  # fmt: skip
    assert lines[0]["message"] == f"running: {team}"
    assert lines[0]["timestamp"] == "1970-01-01T00:00:05.000000007Z"
    assert lines[1]["message"] == 'done; malformed payloads {"x": 2}'
    assert (
        as_dict(decode_kind("log", asm.on("status", key, _status("done"), 1)[0][1]))["message"]
        == "done"
    )  # the end of a process, said or not
    assert lines[3]["message"].startswith("link 1->2 (formation) from epoch 9: ")
    assert asm.gate.skipped.by_channel() == {keys.status(RUN, "agent", 1): 1}  # not agent 1's
