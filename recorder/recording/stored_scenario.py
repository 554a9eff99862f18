"""The scenario stored with a run: the ``scenario`` metadata record of a recording, both ways.

The record holds the resolved scenario as TOML, for a person and for every reader, and
as JSON, which is what :func:`scenario_of` parses when it is there: a TOML parser written
in Python takes most of a second on a team of thousands, the JSON parser a tenth of that.
A recording that holds only the TOML (an older recorder) is read from it.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from typing import Any

from formation.errors import RecordingError
from formation.scenario import Scenario, load_dict

SCENARIO = "scenario"  # the metadata record's name


def scenario_metadata(scenario: Scenario, source: str | None = None) -> dict[str, str]:
    """The record's fields: name, TOML, JSON (the same dict) and, if given, the source file."""
    data = scenario.model_dump(by_alias=True, exclude_none=True)
    fields = {"name": scenario.name, "toml": scenario.to_toml(), "json": json.dumps(data)}
    return fields if source is None else {**fields, "source": source}


def scenario_of(meta: dict[str, dict[str, str]], path: Path) -> Scenario | None:
    """The resolved scenario stored with the run, or None if the recording has none."""
    record = meta.get(SCENARIO, {})
    source = f"{path} (scenario metadata)"
    if (text := record.get("json")) is not None:
        try:
            data: Any = json.loads(text)
        except ValueError as exc:
            raise RecordingError(
                str(path), f"scenario metadata is not valid JSON ({exc})"
            ) from None
        if not isinstance(data, dict):
            raise RecordingError(str(path), "scenario metadata is not a JSON object")
        return load_dict(data, source=source)
    toml = record.get("toml")
    if toml is None:
        return None
    try:
        return load_dict(tomllib.loads(toml), source=source)
    except tomllib.TOMLDecodeError as exc:
        raise RecordingError(str(path), f"scenario metadata is not valid TOML ({exc})") from None


__all__ = ["SCENARIO", "scenario_metadata", "scenario_of"]
