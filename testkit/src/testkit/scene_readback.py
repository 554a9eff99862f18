"""A Foxglove scene as it is recorded (protobuf) and read back through the SDK's schema."""

from __future__ import annotations

from typing import Any

from foxglove.messages import SceneUpdate

from recorder.reading.decoder import as_dict, decode_kind


def check(scene: SceneUpdate) -> dict[str, Any]:
    """The scene as it is recorded (protobuf) and read back by the SDK's schema, as plain data."""
    return as_dict(decode_kind("scene", scene.encode()))
