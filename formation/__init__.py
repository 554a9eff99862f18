"""The shared vocabulary of the testbed: scenario, wire messages, keys, Zenoh config."""

from formation.deadlines import deadline_counts, realtime_accounting
from formation.errors import RecordingError, RuntimeFailure, ScenarioError, TestbedError
from formation.scenario import STRATEGIES, Scenario, load, load_dict

__all__ = [
    "STRATEGIES",
    "RecordingError",
    "RuntimeFailure",
    "Scenario",
    "ScenarioError",
    "TestbedError",
    "deadline_counts",
    "load",
    "load_dict",
    "realtime_accounting",
]
