"""The Foxglove scene: the SDK's SceneUpdate, read back through its protobuf schema, coloured
by link health."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from formation.scenario import Scenario
from recorder.live.scene import BROKEN, HEALTHY, TREE, UNKNOWN, edge_colors, scene_update
from testkit.scene_readback import check

PRIMITIVES = ("arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts", "models")


def test_scene_of_the_paper_formation(paper: Scenario) -> None:
    x = paper.offsets + 0.1
    healthy = np.ones(len(paper.edges), dtype=bool)
    healthy[0] = False
    tree = np.zeros(len(paper.edges), dtype=bool)
    tree[[1, 2, 4, 5]] = True
    scene = check(
        scene_update(
            7,
            1_500_000_000,
            x,
            paper.edge_array,
            paper.offsets,
            paper.reference_agent,
            healthy,
            tree,
        )
    )
    (team,) = scene["entities"]
    assert set(PRIMITIVES) <= set(team)
    assert (team["id"], team["frame_id"]) == ("formation", "world")
    assert team["timestamp"] == "1970-01-01T00:00:01.500Z"
    assert team["metadata"] == [{"key": "epoch", "value": "7"}]
    assert len(team["spheres"]) == paper.n
    assert [s["pose"]["position"]["x"] for s in team["spheres"]] == x[:, 0].tolist()
    assert [t["text"] for t in team["texts"]] == ["1", "2", "3", "4", "5"]
    drawn = sum(len(line["points"]) // 2 for line in team["lines"])
    assert drawn == 2 * len(paper.edges)  # every edge once, plus the desired shape
    assert {line["type"] for line in team["lines"]} == {"LINE_LIST"}
    colours = [(ln["color"]["r"], ln["thickness"], len(ln["points"]) // 2) for ln in team["lines"]]
    edges = len(paper.edges)
    assert sorted(colours) == sorted(
        [(BROKEN[0], 2.0, 1), (HEALTHY[0], 2.0, edges - 5), (TREE[0], 4.0, 4), (0.5, 1.0, edges)]
    )  # the broken edge 1-2, the healthy ones, the tree, the desired shape


def test_edge_colours() -> None:
    healthy = np.array([True, False, True])
    tree = np.array([True, False, False])
    assert edge_colors(healthy, tree, 3) == [TREE, BROKEN, HEALTHY]
    assert edge_colors(None, None, 2) == [UNKNOWN, UNKNOWN]


@settings(max_examples=25, deadline=None)
@given(
    x=arrays(np.float64, (4, 3), elements=st.floats(-1e3, 1e3)),
    healthy=arrays(np.bool_, (5,)),
)
def test_any_3d_scene_decodes(x: np.ndarray, healthy: np.ndarray) -> None:
    edges = np.array([[1, 2], [2, 3], [3, 4], [1, 4], [1, 3]])
    offsets = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 1]])
    scene = check(scene_update(0, 0, x, edges, offsets, 1, healthy, ~healthy))
    assert {s["pose"]["position"]["z"] for s in scene["entities"][0]["spheres"]} == set(x[:, 2])


def test_a_large_team_labels_only_the_leader_and_the_agents_out() -> None:
    from testbed.sim.team_generators import rigid_team

    s = rigid_team(400, 2, 0.1, seed=2, reference_agent=7)
    out = np.zeros(s.n, dtype=bool)
    out[[10, 20]] = True
    scene = check(
        scene_update(3, 0, s.offsets, s.edge_array, s.offsets, s.reference_agent, out=out)
    )
    (team,) = scene["entities"]
    assert sorted(t["text"] for t in team["texts"]) == ["11 out", "21 out", "7"]
    assert len(team["spheres"]) == s.n
    spacing = np.median(
        np.linalg.norm(
            s.offsets[s.edge_array[:, 0] - 1] - s.offsets[s.edge_array[:, 1] - 1], axis=1
        )
    )
    assert team["spheres"][0]["size"]["x"] <= 0.5 * spacing + 1e-12  # no smear of spheres
