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
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cache
from typing import Any

from foxglove.messages import FrameTransforms, Log, SceneUpdate
from pydantic import BaseModel, ConfigDict

from formation import keys
from formation.messages import (
    AgentEstimate,
    Bundle,
    CoordinationState,
    DecisionBatch,
    Delivery,
    DeliveryBatch,
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


# Channel kinds (recorded in each channel's metadata) by the formation.keys function of the key.
_KINDS: dict[str, str] = {
    "agent_state": "agent_state",
    "agent_report": "agent_report",
    "pool_bundle": "pool_bundle",
    "pool_states": "state_bundle",
    "leader_estimate_out": "leader_estimate",
    "leader_estimate_for": "agent_estimate",
    "leader_estimates": "estimate_bundle",
    "link_state": "link_state",
    "link_report": "leader_report",
    "link_estimate": "link_estimate",
    "inbox": "delivery",
    "inbox_pool": "delivery_batch",
    "netem_decision": "decision",
    "netem_change": "link_change",
    "status": "status",
    "metrics": "metrics",
    "scene": "scene",
    "frames": "tf",
    "log": "log",
    "alive": "alive",
}

MESSAGE_MODELS: dict[str, type[BaseModel]] = {
    "agent_state": CoordinationState,
    "link_state": CoordinationState,
    "agent_report": TokenReport,
    "leader_report": TokenReport,
    "leader_estimate": LeaderEstimate,
    "agent_estimate": AgentEstimate,
    "estimate_bundle": Bundle,
    "pool_bundle": Bundle,
    "state_bundle": Bundle,
    "link_estimate": AgentEstimate,
    "delivery": Delivery,
    "delivery_batch": DeliveryBatch,
    "decision": DecisionBatch,
    "link_change": LinkChange,
    "status": Status,
    "metrics": EpochMetrics,
    "alive": LivelinessEvent,
}


def classify(key: str) -> str:
    """The channel kind of ``key`` (``"agent_state"``, ``"scene"``, ... or ``"unknown"``)."""
    parsed = keys.parse(key)
    return ROS2 + parsed.args[-1] if parsed.kind == "body" else _KINDS.get(parsed.kind, UNKNOWN)


def run_id_of(key: str) -> str | None:
    """The run id in ``formation/<run_id>/...``, or None for a key outside the testbed's root."""
    return keys.parse(key).run_id or None


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


def derived_channels(channels: Mapping[int, Any]) -> set[int] | None:
    """Channel ids the recorder wrote itself, or None for a recording that does not mark them
    (older recorders wrote metrics and scenes on the received key's channel)."""
    marked = {cid for cid, ch in channels.items() if ch.metadata.get(ORIGIN) == RECORDER}
    return marked or None


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
    "derived_channels",
    "foxglove_schema",
    "message_encoding",
    "model_schema",
    "ros2_schema",
    "run_id_of",
    "schema_for_key",
    "schema_for_kind",
]
