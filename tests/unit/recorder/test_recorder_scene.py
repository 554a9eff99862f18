"""The Foxglove scene: valid against Foxglove's own SceneUpdate schema, coloured by link health."""

from __future__ import annotations

from typing import Any

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from jsonschema.validators import validator_for

from formation.scenario import Scenario
from recorder.scene import BROKEN, HEALTHY, TREE, UNKNOWN, edge_colors, scene_update

PRIMITIVES = ("arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts", "models")


def check(scene: dict[str, Any], schema: dict[str, Any]) -> None:
    errors = list(validator_for(schema)(schema).iter_errors(scene))
    assert errors == [], errors[0].message if errors else ""


def test_scene_of_the_paper_formation(paper: Scenario, scene_schema: dict[str, Any]) -> None:
    x = paper.offsets + 0.1
    healthy = np.ones(len(paper.edges), dtype=bool)
    healthy[0] = False
    tree = np.zeros(len(paper.edges), dtype=bool)
    tree[[1, 2, 4, 5]] = True
    scene = scene_update(
        7, 1_500_000_000, x, paper.edge_array, paper.offsets, paper.leader, healthy, tree
    )
    check(scene, scene_schema)
    (team,) = scene["entities"]
    assert set(PRIMITIVES) <= set(team)
    assert team["timestamp"] == {"sec": 1, "nsec": 500_000_000}
    assert team["metadata"] == [{"key": "epoch", "value": "7"}]
    assert len(team["spheres"]) == paper.n
    assert [s["pose"]["position"]["x"] for s in team["spheres"]] == x[:, 0].tolist()
    assert [t["text"] for t in team["texts"]] == ["1", "2", "3", "4", "5"]
    drawn = sum(len(line["points"]) // 2 for line in team["lines"])
    assert drawn == 2 * len(paper.edges)  # every edge once, plus the desired shape


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
def test_any_3d_scene_is_valid(
    x: np.ndarray, healthy: np.ndarray, scene_schema: dict[str, Any]
) -> None:
    edges = np.array([[1, 2], [2, 3], [3, 4], [1, 4], [1, 3]])
    offsets = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 1]])
    scene = scene_update(0, 0, x, edges, offsets, 1, healthy, ~healthy)
    check(scene, scene_schema)
    assert {s["pose"]["position"]["z"] for s in scene["entities"][0]["spheres"]} == set(x[:, 2])
