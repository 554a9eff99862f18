"""The scenario stored with a run: read from its JSON, or from the TOML of an older recorder."""

from __future__ import annotations

from pathlib import Path

import pytest

from formation.errors import RecordingError, ScenarioError
from formation.scenario import Scenario
from formation.shipped_scenarios import resolve
from recorder.recording.stored_scenario import SCENARIO, scenario_metadata, scenario_of

FILE = Path("run.mcap")


@pytest.mark.parametrize("name", ["paper", "octahedron3d", "robots", "wifi", "events"])
def test_the_json_gives_the_scenario_the_toml_gives(name: str) -> None:
    scenario = Scenario.from_file(resolve(name))
    record = scenario_metadata(scenario, "here.toml")
    from_json = scenario_of({SCENARIO: {"json": record["json"]}}, FILE)
    from_toml = scenario_of({SCENARIO: {"toml": record["toml"]}}, FILE)
    assert from_json == from_toml == scenario
    assert record["source"] == "here.toml" and record["name"] == scenario.name


def test_the_json_is_read_before_the_toml() -> None:
    """A recording with both is read from its JSON (the TOML here is not even TOML)."""
    record = scenario_metadata(Scenario.from_file(resolve("paper")))
    assert scenario_of({SCENARIO: {**record, "toml": "not = [toml"}}, FILE) is not None


def test_no_scenario_stored() -> None:
    assert scenario_of({}, FILE) is None


@pytest.mark.parametrize(
    ("text", "problem"),
    [("{", "not valid JSON"), ("[1, 2]", "not a JSON object")],
)
def test_a_broken_json_names_the_file(text: str, problem: str) -> None:
    with pytest.raises(RecordingError, match=rf"run\.mcap.*{problem}"):
        scenario_of({SCENARIO: {"json": text}}, FILE)


def test_a_wrong_field_in_the_json_names_the_file_and_field() -> None:
    with pytest.raises(ScenarioError, match=r"run\.mcap \(scenario metadata\).*epochs"):
        scenario_of({SCENARIO: {"json": '{"epochs": -3}'}}, FILE)
