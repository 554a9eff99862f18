"""Decoding the recording's protobuf messages: the scene, the agents' frames, the log.

Foxglove's SDK encodes its typed messages (``foxglove.messages.SceneUpdate(...).encode()``)
but cannot read them back, so the ``protobuf`` package builds each message class from a
schema's FileDescriptorSet (``descriptor_pool`` and ``message_factory.GetMessageClass``):
either the schema a recording's channel carries or the SDK's own
(:func:`recorder.recording.schemas.foxglove_schema`). A payload that does not parse raises
:class:`DecodeError`; nothing else here raises on a payload.
"""

from __future__ import annotations

from functools import cache
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, json_format, message_factory
from google.protobuf.message import DecodeError, Message

from recorder.recording.schemas import foxglove_schema


@cache
def message_class(name: str, schema_data: bytes) -> type[Message]:
    """The message class ``name`` (e.g. ``foxglove.SceneUpdate``) of a FileDescriptorSet.

    Raises :class:`DecodeError` if the schema does not parse or lacks ``name``.
    """
    try:
        files = descriptor_pb2.FileDescriptorSet.FromString(schema_data)
        pool = descriptor_pool.DescriptorPool()  # one per schema: no clash between recordings
        for proto in files.file:
            pool.Add(proto)
        cls: type[Message] = message_factory.GetMessageClass(pool.FindMessageTypeByName(name))
        return cls
    except (DecodeError, KeyError, TypeError) as exc:
        raise DecodeError(f"schema {name}: {exc}") from None


def decode(name: str, schema_data: bytes, payload: bytes) -> Message:
    """``payload`` as the message ``name`` of the schema ``schema_data``."""
    return message_class(name, schema_data).FromString(payload)


def decode_kind(kind: str, payload: bytes) -> Message:
    """``payload`` of a recorder channel ``kind`` (``scene``, ``tf``, ``log``) by the SDK's schema."""
    spec = foxglove_schema(kind)
    return decode(spec.name, spec.data, payload)


@cache
def _scene_outline() -> type[Message]:
    """``foxglove.SceneUpdate`` whose entities declare only their ``id``: their primitives
    stay unknown fields, framed but not parsed."""
    spec = foxglove_schema("scene")
    files = descriptor_pb2.FileDescriptorSet.FromString(spec.data)
    for proto in files.file:
        for message in proto.message_type:
            if message.name == "SceneEntity":
                kept = [f for f in message.field if f.name == "id"]
                del message.field[:]
                message.field.extend(kept)
    pool = descriptor_pool.DescriptorPool()
    for proto in files.file:
        pool.Add(proto)
    cls: type[Message] = message_factory.GetMessageClass(pool.FindMessageTypeByName(spec.name))
    return cls


def scene_outline(payload: bytes) -> Message:
    """A scene's outline: its wire format down to each entity's fields, and the entities'
    ids; what the primitives hold is not parsed."""
    return _scene_outline().FromString(payload)


def decode_cdr(type_name: str, payload: bytes) -> object:
    """An agent's body traffic: ``payload`` as the ROS 2 message ``type_name`` in CDR, read by
    rosbags (the extra ``ros2``); raises :class:`DecodeError` if it does not parse or rosbags
    is missing."""
    try:
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise DecodeError("rosbags (the extra ros2) reads CDR; it is not installed") from None
    try:
        return get_typestore(Stores.ROS2_KILTED).deserialize_cdr(payload, type_name)
    except Exception as exc:  # rosbags raises several kinds on bad bytes or an unknown type
        raise DecodeError(f"{type_name} in CDR: {exc}") from None


def as_dict(message: Message) -> dict[str, Any]:
    """A decoded message as plain data: proto field names, every field present (zero values
    too), enums by name and timestamps as RFC 3339 strings."""
    out: dict[str, Any] = json_format.MessageToDict(
        message, preserving_proto_field_name=True, always_print_fields_with_no_presence=True
    )
    return out


__all__ = [
    "DecodeError",
    "as_dict",
    "decode",
    "decode_cdr",
    "decode_kind",
    "message_class",
    "scene_outline",
]
