"""The Foxglove layout of the live view, built with the SDK's layouts API.

A 3D panel on the scene in frame ``world`` (the agents' frames from ``/tf``), the formation
and shape error plotted against sim time, netem's decisions of the last batch as
columns, the run's log lines, and the live view's counts. ``foxglove-layout/formation-layout.json`` at the top of the
repository is :func:`layout_json` (a test keeps them equal); import it in Foxglove.
"""

from __future__ import annotations

import json

from foxglove import layouts as fl

from formation.topics import DECISIONS_TOPIC, LOG_TOPIC, METRICS_TOPIC, SCENE_TOPIC, STATS_TOPIC
from recorder.live.scene import FRAME

LAYOUT_FILE = "foxglove-layout/formation-layout.json"  # from the repository's top


def formation_layout() -> fl.Layout:
    """3D scene | (error plot / link table / log / live counts)."""
    scene = fl.ThreeDeePanel(
        title="formation",
        config=fl.ThreeDeeConfig(
            fixed_frame=FRAME,
            follow_tf=FRAME,
            follow_mode="follow-none",
            topics={SCENE_TOPIC: fl.BaseRendererSceneUpdateTopicSettings(visible=True)},
        ),
    )
    errors = fl.PlotPanel(
        title="formation and shape error [m]",
        config=fl.PlotConfig(
            paths=[
                fl.PlotSeries(value=f"{METRICS_TOPIC}.formation_error_m", label="formation error"),
                fl.PlotSeries(value=f"{METRICS_TOPIC}.shape_error_m", label="shape error"),
            ],
            x_axis_val="timestamp",
            show_legend=True,
            y_axis_label="m",
        ),
    )
    links = fl.TablePanel(
        title="netem decisions (each record's link, epoch, seq, judgement)",
        config=fl.TableConfig(topic_path=f"{DECISIONS_TOPIC}.records"),
    )
    log = fl.LogPanel(title="log", config=fl.LogConfig(topic_to_render=LOG_TOPIC, show_name=True))
    counts = fl.RawMessagesPanel(
        title="live view: offered, sent, dropped",
        config=fl.RawMessagesConfig(topic_path=STATS_TOPIC),
    )
    side = fl.SplitContainer(
        direction="column",
        items=[
            fl.SplitItem(proportion=2, content=errors),
            fl.SplitItem(proportion=2, content=links),
            fl.SplitItem(proportion=1, content=log),
            fl.SplitItem(proportion=1, content=counts),
        ],
    )
    return fl.Layout(
        content=fl.SplitContainer(
            direction="row",
            items=[
                fl.SplitItem(proportion=3, content=scene),
                fl.SplitItem(proportion=2, content=side),
            ],
        )
    )


def layout_json() -> str:
    """The layout as the file holds it: indented JSON and a final newline."""
    return json.dumps(json.loads(formation_layout().to_json()), indent=2) + "\n"


__all__ = ["LAYOUT_FILE", "formation_layout", "layout_json"]
