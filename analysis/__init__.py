"""The analysis of a run: its record, metrics, team, safety, queues, summary and DataFrames.

Pure: numpy (and pandas for :func:`frames`, loaded on first use) over arrays and the
scenario; no network, no files. The recorder decodes a recording into a :class:`RunData`
(``recorder.read_run``), the simulator makes one (``SimResult``); both are summarised by
:func:`summarise` and tabled by :func:`frames`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from analysis.air import air_losses
from analysis.membership import (
    edge_mask,
    errors_of_team,
    present,
    spans,
    team_edges,
    team_errors,
    team_shape_error,
)
from analysis.metrics import (
    consistency,
    error_statistics,
    formation_error,
    nees,
    shape_error,
)
from analysis.queues import loss_split
from analysis.record import Decisions, Recorded, RunData, Substitutions
from analysis.safety import safety_counts, safety_lines
from analysis.summary import (
    final_value,
    robot_counts_line,
    run_team_errors,
    summarise,
    tracking_lines,
)
from formation.first_use import load_on_first_use

if TYPE_CHECKING:
    from analysis.tables import Frames, frames

_LAZY = {"Frames": "analysis.tables", "frames": "analysis.tables"}  # pandas loads on first use

__getattr__ = load_on_first_use(__name__, _LAZY)


__all__ = [
    "Decisions",
    "Frames",
    "Recorded",
    "RunData",
    "Substitutions",
    "air_losses",
    "consistency",
    "edge_mask",
    "error_statistics",
    "errors_of_team",
    "final_value",
    "formation_error",
    "frames",
    "loss_split",
    "nees",
    "present",
    "robot_counts_line",
    "run_team_errors",
    "safety_counts",
    "safety_lines",
    "shape_error",
    "spans",
    "summarise",
    "team_edges",
    "team_errors",
    "team_shape_error",
    "tracking_lines",
]
