"""The recorder service: every packet of a run into MCAP, replay, analysis and the report.

``python -m recorder`` records (:mod:`recorder.node`; :func:`record` in a process of ours); the functions here read a recording
back, recover a cut one, replay it, serve it live and write the report. The report functions
import matplotlib, and :func:`load_run` and :func:`export` (the recording as pandas
DataFrames) import pandas, so they load on first use.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from recorder.analysis.deadlines import write_deadlines
from recorder.analysis.membership import present, spans, team_edges, team_errors, team_shape_error
from recorder.analysis.metrics import error_statistics, formation_error, nees, shape_error
from recorder.analysis.queues import loss_split
from recorder.analysis.rundata import RunData, read_run
from recorder.analysis.safety import safety_counts
from recorder.analysis.summary import final_value, summarise
from recorder.live.scene import scene_update
from recorder.live.server import LiveServer
from recorder.node import build_parser as recorder_parser
from recorder.node import main as record
from recorder.playback.player import replay
from recorder.reading.decoder import decode
from recorder.reading.reader import RecordingInfo, describe, validate
from recorder.reading.recovery import Recovered, recover
from recorder.recording.schemas import schema_for_key
from recorder.recording.writer import RecordingWriter

if TYPE_CHECKING:
    from recorder.analysis.dataframes import Run, export, load_run
    from recorder.analysis.report import write_report, write_report_from, write_reports

_LAZY = {
    "write_report": "recorder.analysis.report",  # matplotlib loads on first use
    "write_report_from": "recorder.analysis.report",
    "write_reports": "recorder.analysis.report",
    "load_run": "recorder.analysis.dataframes",  # pandas loads on first use
    "export": "recorder.analysis.dataframes",
    "Run": "recorder.analysis.dataframes",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'recorder' has no attribute {name!r}")


__all__ = [
    "LiveServer",
    "RecordingInfo",
    "RecordingWriter",
    "Recovered",
    "Run",
    "RunData",
    "decode",
    "describe",
    "error_statistics",
    "export",
    "final_value",
    "formation_error",
    "load_run",
    "loss_split",
    "nees",
    "present",
    "read_run",
    "record",
    "recorder_parser",
    "recover",
    "replay",
    "safety_counts",
    "scene_update",
    "schema_for_key",
    "shape_error",
    "spans",
    "summarise",
    "team_edges",
    "team_errors",
    "team_shape_error",
    "validate",
    "write_deadlines",
    "write_report",
    "write_report_from",
    "write_reports",
]
