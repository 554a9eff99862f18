"""The recorder's per-epoch derivations: metrics when all states are in, the scene with health."""

from __future__ import annotations

import json

import numpy as np

from formation import keys
from formation.codec import encode
from formation.messages import CoordinationState, EpochMetrics, LeaderEstimate
from formation.scenario import Scenario
from recorder.epochs import STALE_EPOCHS, EpochAssembler
from recorder.metrics import formation_error, shape_error

RUN = "e1"


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
    assert [key for key, _ in out] == [keys.metrics(RUN)]
    m = EpochMetrics.model_validate_json(out[0][1])
    assert m.epoch == 0 and m.stamp_ns == 42 and m.sender == "recorder"
    assert m.formation_error_m == float(formation_error(x, paper.edge_array, paper.weights))
    assert m.shape_error_m == float(shape_error(x, paper.edge_array, paper.offsets))
    assert m.positions == x.tolist()


def test_scene_waits_for_the_estimate_of_its_epoch(paper: Scenario) -> None:
    asm = EpochAssembler(paper, RUN)
    feed_epoch(asm, 0, paper.offsets)
    healthy = [(1, 3), (2, 3), (2, 4), (1, 4), (3, 5), (4, 5)]  # 1-2 down
    out = asm.on_estimate(
        keys.leader_estimate_out(RUN), estimate(paper, 0, healthy, [(1, 3), (1, 4)]), 5
    )
    assert [key for key, _ in out] == [keys.scene(RUN)]
    scene = json.loads(out[0][1])
    lines = scene["entities"][0]["lines"]
    colors = {(ln["color"]["r"], ln["color"]["g"]): len(ln["points"]) // 2 for ln in lines}
    assert colors[(0.84, 0.15)] == 1  # the broken edge 1-2
    assert colors[(1.0, 0.84)] == 2  # tree edges


def test_scene_without_estimate_goes_out_when_a_later_epoch_completes(paper: Scenario) -> None:
    asm = EpochAssembler(paper, RUN)
    feed_epoch(asm, 0, paper.offsets)
    out = feed_epoch(asm, 1, paper.offsets)
    assert [key for key, _ in out] == [keys.metrics(RUN), keys.scene(RUN)]
    assert json.loads(out[1][1])["entities"][0]["metadata"][0]["value"] == "0"
    final = asm.finish(9)
    assert [json.loads(p)["entities"][0]["metadata"][0]["value"] for _, p in final] == ["1"]
    assert asm.finish(9) == []


def test_malformed_states_are_counted_and_stale_epochs_given_up(paper: Scenario) -> None:
    asm = EpochAssembler(paper, RUN)
    assert asm.on_state(keys.agent_state(RUN, 1), b"{not json", 0) == []
    assert asm.gate.skipped.by_channel()[keys.agent_state(RUN, 1)] == 1
    asm.on_state(*state(1, 0, paper.offsets[0]), stamp_ns=0)  # epoch 0 never completes
    for k in range(1, STALE_EPOCHS + 3):
        feed_epoch(asm, k, paper.offsets)
    assert asm.given_up == 1
