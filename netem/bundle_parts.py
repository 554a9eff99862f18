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


def raw_bundle(payload: bytes) -> Any:
    """``payload`` as a bundle whose every part's ``message`` is its JSON string as orjson
    writes it (an :class:`Escaped`), or None where only the model can read it."""
    try:
        bundle = _RAW_BUNDLE.decode(payload)
    except msgspec.DecodeError:  # ValidationError too
        return None
    for part in bundle.parts:
        if as_written(bytes(part.message)) is None:
            return None
    return bundle


def as_written(raw: bytes) -> bytes | None:
    """``raw`` (a JSON value, syntax checked) if it is a string as orjson writes it: no
    ``\\u`` or ``\\/`` escape (orjson writes a character as itself where it can), UTF-8."""
    if raw[:1] != b'"' or b"\\u" in raw or b"\\/" in raw:
        return None
    if not raw.isascii():
        try:
            raw.decode()
        except UnicodeDecodeError:
            return None
    return raw


def read_bundle(malformed: Malformed, key: str, payload: bytes) -> Any:
    """``payload`` as a bundle, its messages as written (:func:`raw_bundle`) or else as the
    model reads them; None when it is malformed (counted on ``key``)."""
    bundle = raw_bundle(payload)
    return bundle if bundle is not None else malformed.read(key, payload, Bundle)


def payloads_of(parts: list[Any]) -> list[Escaped] | list[bytes]:
    """The payloads of a bundle's parts (of :func:`read_bundle`)."""
    if parts and type(parts[0].message) is msgspec.Raw:
        return [Escaped(bytes(part.message)) for part in parts]
    return [part.message.encode() for part in parts]


__all__ = ["as_written", "payloads_of", "raw_bundle", "read_bundle"]
