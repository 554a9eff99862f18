"""The shipped Foxglove layout is the one recorder/live/foxglove_layout.py builds, on the live view's topics."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from formation.topics import DECISIONS_TOPIC, LOG_TOPIC, METRICS_TOPIC, SCENE_TOPIC
from recorder.live.foxglove_layout import LAYOUT_FILE, layout_json

ROOT = Path(__file__).resolve().parents[3]


def _panels(node: dict[str, Any]) -> list[dict[str, Any]]:
    if node.get("type") == "panel":
        return [node]
    return [p for item in node.get("items", []) for p in _panels(item["content"])]


def test_the_shipped_layout_is_the_generated_one() -> None:
    assert (ROOT / LAYOUT_FILE).read_text() == layout_json(), (
        "regenerate: python -c 'from recorder.live.foxglove_layout import *; "
        'open(LAYOUT_FILE, "w").write(layout_json())\''
    )


def test_it_opens_with_a_3d_panel_error_plots_and_a_link_table() -> None:
    panels = {p["panelType"]: p["config"] for p in _panels(json.loads(layout_json())["content"])}
    assert SCENE_TOPIC in panels["ThreeDee"]["topics"]
    assert panels["ThreeDee"]["fixedFrame"] == "world"
    assert [s["value"] for s in panels["Plot"]["paths"]] == [
        f"{METRICS_TOPIC}.formation_error_m",
        f"{METRICS_TOPIC}.shape_error_m",
    ]
    assert panels["Table"]["topicPath"] == f"{DECISIONS_TOPIC}.records"
    assert panels["Log"]["topicToRender"] == LOG_TOPIC
