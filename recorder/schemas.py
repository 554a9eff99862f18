"""Which schema a key carries: key → channel kind → JSON Schema, without parsing a payload.

Key patterns come from :mod:`formation.keys` (built with ``*`` wildcards), so a key
renamed there is followed here. Wire messages get their JSON Schema from the pydantic
model (``model_json_schema()``); ``foxglove.*`` schemas are read from the files in
``shared/schemas/foxglove/`` (env ``FORMATION_SHARED``, else ``../shared`` beside the
repository). When those files cannot be found the channel still gets the schema
*name* Foxglove recognises and a minimal object schema, and :data:`FOXGLOVE_MISSING`
says so; nothing is retyped here.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from functools import cache
from pathlib import Path

from pydantic import BaseModel, ConfigDict

from formation import keys
from formation.messages import (
    AgentEstimate,
    Control,
    CoordinationState,
    DecisionBatch,
    Delivery,
    EpochMetrics,
    LeaderEstimate,
    LinkChange,
    Status,
    TokenReport,
)

JSON = "json"  # message encoding
JSONSCHEMA = "jsonschema"  # schema encoding
UNKNOWN = "unknown"  # schema name of keys this module does not know
SCENE_SCHEMA = "foxglove.SceneUpdate"


class LivelinessEvent(BaseModel):
    """A liveliness token of the run appeared (``alive``) or disappeared; recorded as a log."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: str = "liveliness"
    key: str
    role: str
    ident: str
    alive: bool


_W = "*"  # one chunk of a key expression
# Channel kinds in match order; the pattern is built by formation.keys with wildcards.
_PATTERNS: tuple[tuple[str, str], ...] = (
    ("agent_state", keys.agent_state(_W, _W)),
    ("agent_report", keys.agent_report(_W, _W)),
    ("leader_estimate", keys.leader_estimate_out(_W)),
    ("agent_estimate", keys.leader_estimate_for(_W, _W)),
    ("link_state", keys.link_state(_W, _W, _W)),
    ("leader_report", keys.link_report(_W, _W)),
    ("link_estimate", keys.link_estimate(_W, _W)),
    ("delivery", keys.inbox(_W, _W, _W)),
    ("decision", keys.netem_decision(_W)),
    ("link_change", keys.netem_change(_W)),
    ("status", keys.status(_W, _W, _W)),
    ("control", keys.control(_W)),
    ("metrics", keys.metrics(_W)),
    ("scene", keys.scene(_W)),
    ("alive", keys.alive(_W, _W, _W)),
)
_SPLIT = tuple((kind, tuple(p.split("/"))) for kind, p in _PATTERNS)

MODELS: dict[str, type[BaseModel]] = {
    "agent_state": CoordinationState,
    "link_state": CoordinationState,
    "agent_report": TokenReport,
    "leader_report": TokenReport,
    "leader_estimate": LeaderEstimate,
    "agent_estimate": AgentEstimate,
    "link_estimate": AgentEstimate,
    "delivery": Delivery,
    "decision": DecisionBatch,
    "link_change": LinkChange,
    "status": Status,
    "control": Control,
    "metrics": EpochMetrics,
    "alive": LivelinessEvent,
}


def classify(key: str) -> str:
    """The channel kind of ``key`` (``"agent_state"``, ``"scene"``, ... or ``"unknown"``)."""
    parts = key.split("/")
    for kind, pattern in _SPLIT:
        if len(parts) == len(pattern) and all(
            p in (_W, x) for p, x in zip(pattern, parts, strict=True)
        ):
            return kind
    return UNKNOWN


def run_id_of(key: str) -> str | None:
    """The run id in ``formation/<run_id>/...``, or None for a key outside the testbed's root."""
    parts = key.split("/")
    return parts[1] if len(parts) > 2 and parts[0] == keys.ROOT else None


@dataclass(frozen=True)
class SchemaSpec:
    """What an MCAP schema record holds: name, encoding and the schema bytes."""

    name: str
    encoding: str
    data: bytes


@cache
def model_schema(model: type[BaseModel]) -> SchemaSpec:
    """The JSON Schema of a wire model, named ``formation.<Model>``."""
    data = json.dumps(model.model_json_schema(), separators=(",", ":")).encode()
    return SchemaSpec(f"formation.{model.__name__}", JSONSCHEMA, data)


def shared_dir() -> Path | None:
    """The shared directory: ``$FORMATION_SHARED`` or ``shared/`` beside the repository root."""
    env = os.environ.get("FORMATION_SHARED")
    candidates = [Path(env)] if env else []
    candidates.append(Path(__file__).resolve().parents[2] / "shared")
    for path in candidates:
        if (path / "schemas" / "foxglove").is_dir():
            return path
    return None


FOXGLOVE_MISSING: list[str] = []  # names of foxglove schemas written without their file


@cache
def foxglove_schema(name: str) -> SchemaSpec:
    """``foxglove.<name>`` from its JSON Schema file; a minimal stand-in if the file is missing."""
    full = f"foxglove.{name}"
    root = shared_dir()
    if root is not None:
        path = root / "schemas" / "foxglove" / f"{name}.json"
        if path.is_file():
            return SchemaSpec(full, JSONSCHEMA, path.read_bytes())
    FOXGLOVE_MISSING.append(full)
    stand_in = {"title": full, "type": "object", "$comment": "schema file not found at recording"}
    return SchemaSpec(full, JSONSCHEMA, json.dumps(stand_in).encode())


UNKNOWN_SCHEMA = SchemaSpec(UNKNOWN, JSONSCHEMA, b"{}")  # the empty schema accepts any JSON


def schema_for_kind(kind: str) -> SchemaSpec:
    """The schema written for channels of ``kind``."""
    if kind == "scene":
        return foxglove_schema("SceneUpdate")
    model = MODELS.get(kind)
    return UNKNOWN_SCHEMA if model is None else model_schema(model)


def schema_for_key(key: str) -> SchemaSpec:
    return schema_for_kind(classify(key))


__all__ = [
    "FOXGLOVE_MISSING",
    "JSON",
    "JSONSCHEMA",
    "MODELS",
    "SCENE_SCHEMA",
    "UNKNOWN",
    "UNKNOWN_SCHEMA",
    "LivelinessEvent",
    "SchemaSpec",
    "classify",
    "foxglove_schema",
    "model_schema",
    "run_id_of",
    "schema_for_key",
    "schema_for_kind",
    "shared_dir",
]
