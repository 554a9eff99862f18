"""The shared vocabulary of the testbed: scenario, wire messages, keys, errors; pure (no Zenoh)."""

from formation.deadlines import deadline_counts, realtime_accounting
from formation.errors import RecordingError, RuntimeFailure, ScenarioError, TestbedError
from formation.graph import check_dimension
from formation.scenario import STRATEGIES, Scenario, load, load_dict

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
