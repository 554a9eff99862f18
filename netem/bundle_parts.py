"""A :class:`~formation.messages.Bundle`'s parts as netem passes them on: each message as the
JSON string it came in, not unescaped and escaped again.

A delivered packet's ``message`` is its payload as orjson writes a JSON string
(:func:`netem.proxy.records.message_json`). A part's message in a bundle usually is that
string already: the bundle is read with each message kept as its raw JSON (``msgspec.Raw``,
its syntax checked), and a part whose raw string orjson would write otherwise (a ``\\u`` or
``\\/`` escape, bytes not UTF-8) sends the whole bundle to the model's reading
(:meth:`formation.codec.Malformed.read`), which counts it if it is malformed.
"""

from __future__ import annotations

from typing import Any

import msgspec
import numpy as np

from formation.codec import Malformed
from formation.messages import Bundle, BundlePart
from formation.structs import struct_of
from netem.proxy.records import Escaped


def _with(struct: type[msgspec.Struct], name: str, kind: Any) -> type[msgspec.Struct]:
    """``struct`` with the field ``name`` of type ``kind``, as strict as :func:`struct_of`."""
    fields: list[tuple[str, Any] | tuple[str, Any, Any]] = []
    for f in msgspec.structs.fields(struct):
        t = kind if f.name == name else f.type
        fields.append((f.name, t) if f.required else (f.name, t, f.default))
    return msgspec.defstruct(
        struct.__name__, fields, kw_only=True, frozen=True, forbid_unknown_fields=True, gc=False
    )


_RAW_PART = _with(struct_of(BundlePart), "message", msgspec.Raw)
_RAW_BUNDLE = msgspec.json.Decoder(_with(struct_of(Bundle), "parts", list[_RAW_PART]))  # type: ignore[valid-type]


def raw_bundle(payload: bytes) -> tuple[Any, list[Escaped]] | None:
    """``payload`` as a bundle and its parts' payloads, each message the JSON string orjson
    writes of it (an :class:`Escaped`); None where only the model can read it."""
    try:
        bundle: Any = _RAW_BUNDLE.decode(payload)
    except msgspec.DecodeError:  # ValidationError too
        return None
    if not as_written(payload):
        return None
    messages = [bytes(part.message) for part in bundle.parts]
    if not all(m[0] == _QUOTE for m in messages):
        return None  # a message that is not a string: the model names it
    return bundle, list(map(Escaped, messages))


_QUOTE, _BACKSLASH = ord('"'), ord("\\")


def as_written(payload: bytes) -> bool:
    """Whether every JSON string in ``payload`` (its syntax checked) is as orjson writes it:
    UTF-8, and ``\\"`` its only escape (orjson writes ``/`` and a character it need not
    escape as themselves; a message holds no control character)."""
    if not payload.isascii():
        try:
            payload.decode()
        except UnicodeDecodeError:
            return False
    text = np.frombuffer(payload, np.uint8)
    after = np.flatnonzero(text == _BACKSLASH) + 1  # never past the end: inside a string
    return bool((text[after] == _QUOTE).all())


def read_bundle(malformed: Malformed, key: str, payload: bytes) -> tuple[Any, list[Any]] | None:
    """``payload`` as a bundle and its parts' payloads, as written (:func:`raw_bundle`) or
    else as the model reads them; None when it is malformed (counted on ``key``)."""
    got = raw_bundle(payload)
    if got is not None:
        return got
    bundle = malformed.read(key, payload, Bundle)
    if bundle is None:
        return None
    return bundle, [part.message.encode() for part in bundle.parts]


__all__ = ["as_written", "raw_bundle", "read_bundle"]
