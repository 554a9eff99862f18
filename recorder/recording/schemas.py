"""Which schema a key carries: key → channel kind → schema and encoding, without parsing a payload.

Key patterns come from :mod:`formation.keys` (built with ``*`` wildcards), so a key
renamed there is followed here. Wire messages are JSON with the JSON Schema of their
pydantic model (``model_json_schema()``); what Foxglove's panels read (the scene, the
agents' frames, the log) is protobuf with the schema of the SDK's typed message
(``foxglove.messages.X.get_schema()``, a FileDescriptorSet). Nothing is retyped or copied
here, and a recording always carries the real schema.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cache

from foxglove.messages import FrameTransforms, Log, SceneUpdate
from pydantic import BaseModel, ConfigDict

from formation import keys
from formation.messages import (
    AgentEstimate,
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
PROTOBUF = "protobuf"  # message and schema encoding of the Foxglove channels
UNKNOWN = "unknown"  # schema name of keys this module does not know
ROS2MSG = "ros2msg"  # schema encoding of an agent's body traffic: ROS 2's message definition
CDR = "cdr"  # its message encoding
ROS2 = "ros2:"  # kind of a body channel: "ros2:" and the message type
ORIGIN = "origin"  # channel metadata of what the recorder derived itself
RECORDER = "recorder"  # ORIGIN's value on those channels
FoxgloveMessage = type[SceneUpdate] | type[FrameTransforms] | type[Log]
# The recorder's channels that Foxglove's panels read, by kind: the SDK's typed message.
FOXGLOVE: dict[str, FoxgloveMessage] = {"scene": SceneUpdate, "tf": FrameTransforms, "log": Log}


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
    ("metrics", keys.metrics(_W)),
    ("scene", keys.scene(_W)),
    ("tf", keys.frames(_W)),
    ("log", keys.log(_W)),
    ("alive", keys.alive(_W, _W, _W)),
)
_SPLIT = tuple((kind, tuple(p.split("/"))) for kind, p in _PATTERNS)
# an agent's body traffic: the kind names the ROS 2 type, the key's last three chunks
_BODY = tuple(keys.body(_W, _W, _W, f"{_W}/msg/{_W}").split("/"))

MESSAGE_MODELS: dict[str, type[BaseModel]] = {
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
    "metrics": EpochMetrics,
    "alive": LivelinessEvent,
}


def classify(key: str) -> str:
    """The channel kind of ``key`` (``"agent_state"``, ``"scene"``, ... or ``"unknown"``)."""
    parts = key.split("/")
    if len(parts) == len(_BODY) and all(p in (_W, x) for p, x in zip(_BODY, parts, strict=True)):
        return ROS2 + "/".join(parts[-3:])
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


@cache
def foxglove_schema(kind: str) -> SchemaSpec:
    """The SDK's protobuf schema of the Foxglove channel ``kind`` (:data:`FOXGLOVE`)."""
    schema = FOXGLOVE[kind].get_schema()
    return SchemaSpec(schema.name, schema.encoding, bytes(schema.data))


UNKNOWN_SCHEMA = SchemaSpec(UNKNOWN, JSONSCHEMA, b"{}")  # the empty schema accepts any JSON


@cache
def ros2_schema(type_name: str) -> SchemaSpec:
    """ROS 2's definition of ``type_name`` with its dependencies (``ros2msg``), as Foxglove
    reads it; from rosbags (the extra ``ros2``), empty where it is not installed."""
    try:
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        return SchemaSpec(type_name, ROS2MSG, b"")
    text, _ = get_typestore(Stores.ROS2_KILTED).generate_msgdef(type_name, ros_version=2)
    return SchemaSpec(type_name, ROS2MSG, text.encode())


class CdrMessage(BaseModel):
    """A body channel's message that decoded as its ROS 2 type (recorder.reading.trust)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    type_name: str
    size: int


def schema_for_kind(kind: str) -> SchemaSpec:
    """The schema written for channels of ``kind``."""
    if kind.startswith(ROS2):
        return ros2_schema(kind.removeprefix(ROS2))
    if kind in FOXGLOVE:
        return foxglove_schema(kind)
    model = MESSAGE_MODELS.get(kind)
    return UNKNOWN_SCHEMA if model is None else model_schema(model)


def schema_for_key(key: str) -> SchemaSpec:
    return schema_for_kind(classify(key))


def message_encoding(kind: str) -> str:
    """How messages of channels of ``kind`` are encoded: protobuf for Foxglove's, CDR for an
    agent's body traffic, else JSON."""
    if kind.startswith(ROS2):
        return CDR
    return PROTOBUF if kind in FOXGLOVE else JSON


__all__ = [
    "CDR",
    "FOXGLOVE",
    "JSON",
    "JSONSCHEMA",
    "MESSAGE_MODELS",
    "PROTOBUF",
    "ROS2",
    "ROS2MSG",
    "UNKNOWN",
    "UNKNOWN_SCHEMA",
    "CdrMessage",
    "LivelinessEvent",
    "SchemaSpec",
    "classify",
    "foxglove_schema",
    "message_encoding",
    "model_schema",
    "ros2_schema",
    "run_id_of",
    "schema_for_key",
    "schema_for_kind",
]
