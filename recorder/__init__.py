"""The recorder service: every packet of a run into MCAP, replay, the reading and the report.

``python -m recorder`` records (:mod:`recorder.node`; :func:`main` in a process of ours); the
functions here read a recording back (:func:`read_run`, the one decoder of a recording, into
an :class:`analysis.RunData`), recover a cut one, replay it, serve it live and write the
report. The report functions import matplotlib, and :func:`load_run` and :func:`export` (the
recording as pandas DataFrames) import pandas, so they load on first use.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from formation.first_use import load_on_first_use
from recorder.node import build_parser as recorder_parser
from recorder.node import main
from recorder.playback.player import replay
from recorder.reading.reader import RecordingInfo, describe, validate
from recorder.reading.recovery import Recovered, recover
from recorder.reading.run import read_run
from recorder.reporting.conclusion import (
    KEEP_M,
    Evidence,
    evidence,
    fallback_clause,
    graph_clause,
    why_identical,
)
from recorder.reporting.deadlines import write_deadlines
from recorder.reporting.style import THRESHOLD_COLOUR, Look, look, palette

if TYPE_CHECKING:
    from recorder.reading.dataframes import export, load_run
    from recorder.reporting.report import write_report, write_report_from, write_reports

_LAZY = {
    "write_report": "recorder.reporting.report",  # matplotlib loads on first use
    "write_report_from": "recorder.reporting.report",
    "write_reports": "recorder.reporting.report",
    "load_run": "recorder.reading.dataframes",  # pandas loads on first use
    "export": "recorder.reading.dataframes",
}

__getattr__ = load_on_first_use(__name__, _LAZY)


__all__ = [
    "KEEP_M",
    "THRESHOLD_COLOUR",
    "Evidence",
    "Look",
    "RecordingInfo",
    "Recovered",
    "describe",
    "evidence",
    "export",
    "fallback_clause",
    "graph_clause",
    "load_run",
    "look",
    "main",
    "palette",
    "read_run",
    "recorder_parser",
    "recover",
    "replay",
    "validate",
    "why_identical",
    "write_deadlines",
    "write_report",
    "write_report_from",
    "write_reports",
]
