"""JSON on the wire: one place encodes and decodes every message, and counts what fails."""

from __future__ import annotations

import struct
import time
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from itertools import chain
from typing import Any, TypeVar

import msgspec
from pydantic import BaseModel, ValidationError

from formation.messages import DeliveredPacket
from formation.structs import decoder_of, plain_of

M = TypeVar("M", bound=BaseModel)

# Attachment: the routing facts netem needs without parsing the payload.
_ATTACH = struct.Struct("<qqq")  # epoch, seq, source


def encode(message: BaseModel) -> bytes:
    return message.model_dump_json().encode()


def decode(payload: bytes, model: type[M]) -> M:
    return model.model_validate_json(payload)


def attachment(epoch: int, seq: int, source: int) -> bytes:
    return _ATTACH.pack(epoch, seq, source)


def read_attachment(data: bytes | None) -> tuple[int, int, int] | None:
    """``(epoch, seq, source)``, or None when absent or malformed."""
    if data is None or len(data) != _ATTACH.size:
        return None
    epoch, seq, source = _ATTACH.unpack(data)
    return int(epoch), int(seq), int(source)


def now_ns() -> int:
    return time.monotonic_ns()


class Malformed:
    """Counts payloads that failed validation, per key; never raises."""

    def __init__(self) -> None:
        self.counts: Counter[str] = Counter()

    def decode(self, key: str, payload: bytes | str, model: type[M]) -> M | None:
        try:
            return model.model_validate_json(payload)
        except (ValidationError, ValueError, UnicodeDecodeError):
            self.counts[key] += 1
            return None

    def read(self, key: str, payload: bytes | str, model: type[BaseModel]) -> Any:
        """``payload`` with ``model``'s fields: a struct of them where msgspec can vouch for it
        (:func:`formation.structs.plain_of`), else the model; None when it fails validation
        (counted on ``key``). For messages read by the hundred an epoch."""
        plain = plain_of(model, payload)
        return plain if plain is not None else self.decode(key, payload, model)

    def decode_packets(
        self,
        packets: Iterable[DeliveredPacket],
        model: type[BaseModel],
        key_of: Callable[[DeliveredPacket], str],
        belongs: Callable[[DeliveredPacket, Any], bool],
        memo: dict[int, tuple[DeliveredPacket, Any]] | None = None,
    ) -> Iterator[tuple[DeliveredPacket, Any]]:
        """The payloads of a delivery's packets with ``model``'s fields (as :meth:`read`),
        lazily. One that fails validation, or that ``belongs`` says its link cannot carry, is
        counted on its link's key (``key_of``, built only then) and skipped. ``memo``: packet
        objects already decoded (a pool's batch shares one among its receivers), and theirs."""
        for p in packets:
            known = memo.get(id(p)) if memo is not None else None
            if known is not None and known[0] is p:  # the entry keeps p: its id is not reused
                msg = known[1]
            else:
                msg = _payload(model, p.message)
                if memo is not None:
                    memo[id(p)] = (p, msg)
            if msg is not None and belongs(p, msg):
                yield p, msg
            else:
                self.counts[key_of(p)] += 1


def payloads(model: type[BaseModel], packets: Iterable[DeliveredPacket]) -> list[Any]:
    """Each packet's payload with ``model``'s fields (as :meth:`Malformed.read`), or None
    where it fails validation: the caller counts it on its link's key.

    Each message is decoded on its own, never joined to the others: in one array a sender's
    two malformed messages around another's could shift its slot to a value they wrote."""
    messages = [p.message for p in packets]
    try:
        return list(map(decoder_of(model).decode, messages))
    except msgspec.DecodeError:
        return [_payload(model, m) for m in messages]


def _payload(model: type[BaseModel], message: str) -> Any:
    msg = plain_of(model, message)
    if msg is None:
        try:
            msg = model.model_validate_json(message)
        except (ValidationError, ValueError, UnicodeDecodeError):
            return None
    return msg


def batched_deliveries(batch: Any) -> list[tuple[Any, list[int]]] | None:
    """A :class:`~formation.messages.DeliveryBatch`'s deliveries (its fields), each with the
    indices of its packets in the batch's table (``batch.packets``); a malformed one (packets
    of its own, an index outside the table) is left out. None when its columns
    ``deliveries`` and ``carried`` differ in length (no delivery's packets can be told)."""
    deliveries, carried = batch.deliveries, batch.carried
    if len(carried) != len(deliveries):
        return None
    size = len(batch.packets)
    rows = list(chain.from_iterable(carried))
    if (not rows or (min(rows) >= 0 and max(rows) < size)) and not any(
        d.packets for d in deliveries
    ):
        return list(zip(deliveries, carried, strict=True))  # every one whole: checked at once
    return [
        (d, ids)
        for d, ids in zip(deliveries, carried, strict=True)
        if not d.packets and not (ids and (min(ids) < 0 or max(ids) >= size))
    ]


__all__ = [
    "Malformed",
    "attachment",
    "batched_deliveries",
    "decode",
    "encode",
    "now_ns",
    "payloads",
    "read_attachment",
]
