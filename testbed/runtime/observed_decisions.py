"""netem's decision batches as the launcher's observer keeps them: drops counted on arrival,
the records left as the bytes they came in until a run's summary asks for them."""

from __future__ import annotations

import json
from typing import NamedTuple

import msgspec
import orjson

from formation.messages import LINK_CLASS_OF

COLUMNS = ("source", "target", "epoch", "seq")  # a record's fields before its judgement
_DIGITS = b"0123456789,-"


class Judged(NamedTuple):
    """A decision batch as kept: its link class, its judgements (verdict, model), its columns
    (``COLUMNS``; a JSON array of integers, or the values already read) and judgement column."""

    link_class: str
    judged: list[tuple[str, str]]
    columns: tuple[bytes | list[int], ...]
    judgement: list[int]

    @property
    def drops(self) -> int:
        return sum(self.judgement.count(j) for j, (v, _) in enumerate(self.judged) if v == "drop")

    def records(self) -> list[tuple[int, int, int, int, int]]:
        """(source, target, epoch, seq, judgement) of each record."""
        columns = [_integers(c) if isinstance(c, bytes) else c for c in self.columns]
        return list(zip(*columns, self.judgement, strict=True))


def _integers(raw: bytes) -> list[int]:
    try:
        return list(orjson.loads(raw))
    except orjson.JSONDecodeError:  # an integer past 64 bits
        return list(json.loads(raw))


class _Judgement(msgspec.Struct, gc=False):
    verdict: str
    model: str = ""


class _Columns(msgspec.Struct, gc=False):
    source: msgspec.Raw
    target: msgspec.Raw
    epoch: msgspec.Raw
    seq: msgspec.Raw
    judgement: list[int]


class _Batch(msgspec.Struct, gc=False):
    phase: str
    judgements: list[_Judgement]
    records: _Columns


_BATCH = msgspec.json.Decoder(_Batch)


def _length(raw: bytes) -> int | None:
    """How many integers the JSON array ``raw`` holds (msgspec checked it is JSON); None
    unless it holds nothing else."""
    if raw.translate(None, _DIGITS) != b"[]":
        return None
    return 0 if raw == b"[]" else raw.count(b",") + 1


def read_batch(payload: bytes) -> Judged | None:
    """A decision batch with its drops countable; None if it is malformed (its columns of
    unequal lengths, a judgement index out of range)."""
    try:
        batch = _BATCH.decode(payload)
        columns: tuple[bytes | list[int], ...] = tuple(
            bytes(getattr(batch.records, name)) for name in COLUMNS
        )
        lengths = [_length(c) for c in columns]  # type: ignore[arg-type]
        judged = [(j.verdict, j.model) for j in batch.judgements]
        index = batch.records.judgement
        link_class = LINK_CLASS_OF[batch.phase]
    except (msgspec.DecodeError, KeyError):
        return _read_slowly(payload)
    if None in lengths:
        return _read_slowly(payload)
    if any(n != len(index) for n in lengths) or (
        index and not 0 <= min(index) <= max(index) < len(judged)
    ):
        return None
    return Judged(link_class, judged, columns, index)


def _read_slowly(payload: bytes) -> Judged | None:
    """A batch msgspec does not vouch for, read as any JSON (a value of another type is
    kept as it is, as a reader of one record takes it)."""
    try:
        batch = orjson.loads(payload)
        judged = [(str(j["verdict"]), str(j.get("model", ""))) for j in batch["judgements"]]
        records = batch["records"]
        columns = tuple(list(records[name]) for name in COLUMNS)
        index = records["judgement"]
        link_class = LINK_CLASS_OF[batch["phase"]]
        ok = all(type(j) is int for j in index) and all(len(c) == len(index) for c in columns)
        ok = ok and (not index or 0 <= min(index) <= max(index) < len(judged))
    except (orjson.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError):
        return None
    return Judged(link_class, judged, columns, index) if ok else None


__all__ = ["COLUMNS", "Judged", "read_batch"]
