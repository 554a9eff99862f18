"""JSON on the wire: one place encodes and decodes every message, and counts what fails."""

from __future__ import annotations

import struct
import time
from collections import Counter
from typing import TypeVar

from pydantic import BaseModel, TypeAdapter, ValidationError

from formation.messages import Message

M = TypeVar("M", bound=BaseModel)
_ANY: TypeAdapter[Message] = TypeAdapter(Message)

# Attachment: the routing facts netem needs without parsing the payload.
_ATTACH = struct.Struct("<qqq")  # epoch, seq, source
# netem's forwarded copy may add a flags word: bit 0 = a close marker follows for this
# receiver's epoch although every sender's packet arrives (lockstep, ARCHITECTURE.md "Time").
_ATTACH_FLAGS = struct.Struct("<qqqq")
CLOSE_FOLLOWS = 1


def encode(message: BaseModel) -> bytes:
    return message.model_dump_json().encode()


def decode(payload: bytes, model: type[M]) -> M:
    return model.model_validate_json(payload)


def decode_any(payload: bytes) -> Message:
    return _ANY.validate_json(payload)


def attachment(epoch: int, seq: int, source: int, flags: int = 0) -> bytes:
    if flags:
        return _ATTACH_FLAGS.pack(epoch, seq, source, flags)
    return _ATTACH.pack(epoch, seq, source)


def read_attachment(data: bytes | None) -> tuple[int, int, int] | None:
    """``(epoch, seq, source)``, or None when absent or malformed."""
    if data is None:
        return None
    if len(data) == _ATTACH.size:
        epoch, seq, source = _ATTACH.unpack(data)
    elif len(data) == _ATTACH_FLAGS.size:
        epoch, seq, source, _ = _ATTACH_FLAGS.unpack(data)
    else:
        return None
    return int(epoch), int(seq), int(source)


def attachment_flags(data: bytes | None) -> int:
    """The flags word of a forwarded packet's attachment (0 when it has none)."""
    if data is None or len(data) != _ATTACH_FLAGS.size:
        return 0
    return int(_ATTACH_FLAGS.unpack(data)[3])


def now_ns() -> int:
    return time.monotonic_ns()


class Malformed:
    """Counts payloads that failed validation, per key; never raises."""

    def __init__(self) -> None:
        self.counts: Counter[str] = Counter()

    def decode(self, key: str, payload: bytes, model: type[M]) -> M | None:
        try:
            return model.model_validate_json(payload)
        except (ValidationError, ValueError, UnicodeDecodeError):
            self.counts[key] += 1
            return None


__all__ = [
    "CLOSE_FOLLOWS",
    "Malformed",
    "attachment",
    "attachment_flags",
    "decode",
    "decode_any",
    "encode",
    "now_ns",
    "read_attachment",
]
