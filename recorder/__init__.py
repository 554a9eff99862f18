"""The recorder service: every packet of a run into MCAP, replay, analysis and the report.

``python -m recorder`` records (:mod:`recorder.node`); the functions here read a
recording back, recover a cut one and write the report. The report functions
import matplotlib, and :func:`load_run` (the recording as pandas DataFrames) imports
pandas, so they load on first use.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from recorder.membership import spans
from recorder.metrics import error_statistics, formation_error, longest_run, nees, shape_error
from recorder.reader import RecordingInfo, describe, validate
from recorder.recover import Recovered, recover
from recorder.rundata import RunData, read_run
from recorder.writer import RecordingWriter

if TYPE_CHECKING:
    from recorder.frames import Run, load_run
    from recorder.report import write_report, write_report_from

_LAZY = {
    "write_report": "recorder.report",
    "write_report_from": "recorder.report",
    "load_run": "recorder.frames",  # pandas loads on first use
    "Run": "recorder.frames",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'recorder' has no attribute {name!r}")


__all__ = [
    "RecordingInfo",
    "RecordingWriter",
    "Recovered",
    "Run",
    "RunData",
    "describe",
    "error_statistics",
    "formation_error",
    "load_run",
    "longest_run",
    "nees",
    "read_run",
    "recover",
    "shape_error",
    "spans",
    "validate",
    "write_report",
    "write_report_from",
]
