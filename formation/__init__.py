"""The shared vocabulary of the testbed: scenario, wire messages, keys, errors; pure (no Zenoh).

The names below load on first use (PEP 562), so a module that needs only ``formation.errors``
or ``formation.keys`` (a command's ``--help``) does not import numpy and the scenario's models.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from formation.first_use import load_on_first_use

if TYPE_CHECKING:
    from formation.deadlines import deadline_counts, realtime_accounting
    from formation.errors import RecordingError, RuntimeFailure, ScenarioError, TestbedError
    from formation.graph import check_dimension
    from formation.scenario import STRATEGIES, Scenario, load, load_dict

_HOMES = {
    "STRATEGIES": "formation.scenario",
    "RecordingError": "formation.errors",
    "RuntimeFailure": "formation.errors",
    "Scenario": "formation.scenario",
    "ScenarioError": "formation.errors",
    "TestbedError": "formation.errors",
    "check_dimension": "formation.graph",
    "deadline_counts": "formation.deadlines",
    "load": "formation.scenario",
    "load_dict": "formation.scenario",
    "realtime_accounting": "formation.deadlines",
}

__getattr__ = load_on_first_use(__name__, _HOMES)


__all__ = [
    "STRATEGIES",
    "RecordingError",
    "RuntimeFailure",
    "Scenario",
    "ScenarioError",
    "TestbedError",
    "check_dimension",
    "deadline_counts",
    "load",
    "load_dict",
    "realtime_accounting",
]
