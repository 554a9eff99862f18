"""Unicycles' headings in the scene: one arrow per agent along its recorded heading."""

from __future__ import annotations

from typing import Any

import numpy as np

from formation import keys
from formation.scenario import Scenario
from recorder.live.epoch_assembly import EpochAssembler
from recorder.live.scene import scene_update
from recorder.reading.decoder import as_dict, decode_kind
from testbed.sim.simulate import simulate
from testkit.scene_readback import check


def yaw(arrow: dict[str, Any]) -> float:
    q = arrow["pose"]["orientation"]
    assert q["x"] == q["y"] == 0.0
    return float(2.0 * np.arctan2(q["z"], q["w"]))


def test_headings_are_arrows_from_each_agent(paper: Scenario) -> None:
    x = paper.offsets + 0.1
    th = np.array([0.0, np.pi / 2, -2.0, np.nan, 3.0])  # agent 4's heading unknown
    scene = check(
        scene_update(3, 0, x, paper.edge_array, paper.offsets, paper.reference_agent, headings=th)
    )
    (team,) = scene["entities"]
    arrows = team["arrows"]
    assert len(arrows) == 4
    for arrow, i in zip(arrows, (0, 1, 2, 4), strict=True):
        assert np.isclose(yaw(arrow), th[i])
        p = arrow["pose"]["position"]
        assert (p["x"], p["y"]) == (x[i, 0], x[i, 1])
    bare = check(scene_update(3, 0, x, paper.edge_array, paper.offsets, paper.reference_agent))
    assert bare["entities"][0]["arrows"] == []


def test_the_recorder_draws_the_recorded_headings(paper: Scenario, synth: Any) -> None:
    robots = paper.with_overrides(epochs=6, control={"dynamics": "unicycle"})
    result = simulate(robots)
    asm = EpochAssembler(robots, synth.RUN, clock=lambda: 42)
    scenes = []
    for key, payload, _, t in synth.traffic(result):
        kind = (
            "agent_state" if key.endswith("/state") and "/agent/" in key
            else "leader_estimate" if key == keys.leader_estimate_out(synth.RUN)
            else "decision" if key == keys.netem_decision(synth.RUN) else None
        )  # fmt: skip
        if kind is not None:
            scenes += [p for k, p in asm.on(kind, key, payload, t) if k == keys.scene(synth.RUN)]
    assert len(scenes) == robots.epochs + 1
    for k, raw in enumerate(scenes):
        scene = as_dict(decode_kind("scene", raw))
        got = np.array([yaw(a) for a in scene["entities"][0]["arrows"]])
        turn = np.angle(np.exp(1j * (got - result.headings[k])))  # the difference, wrapped
        np.testing.assert_allclose(turn, 0.0, atol=1e-12)
