"""Reading a finished recording: checks with clear errors, its summary (``formation info``), validation.

Every failure is a :class:`~formation.errors.RecordingError` naming the file:
missing, empty, not MCAP, truncated (no footer: the recorder did not finish,
``formation recover`` keeps the complete chunks) or unreadable.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from jsonschema.validators import validator_for
from mcap.reader import McapReader, make_reader
from mcap.records import Channel, Message, Schema
from mcap.summary import Summary

from formation.errors import RecordingError, TestbedError
from formation.messages import LINK_CLASS_OF, DecisionBatch
from formation.scenario import Scenario
from recorder.reading.chunks import Record, file_chunks, file_order
from recorder.reading.decoder import DecodeError, decode, decode_cdr
from recorder.reading.summary import read_metadata, read_summary
from recorder.reading.trust import Gate, Skipped
from recorder.recording.schemas import PROTOBUF, ROS2MSG, classify, derived_channels
from recorder.recording.stored_scenario import scenario_of
from recorder.recording.writer import MAGIC, rotated_path

READ_ERRORS = (Exception,)  # the mcap reader raises McapError, struct.error, zstd/lz4 errors, ...


def check_head(path: Path, when_empty: str = "not an MCAP recording") -> int:
    """Raise :class:`RecordingError` unless ``path`` is a non-empty file starting as MCAP; its size."""
    if not path.exists():
        raise RecordingError(str(path), "no such file")
    if not path.is_file():
        raise RecordingError(str(path), "not a file")
    size = path.stat().st_size
    if size == 0:
        raise RecordingError(str(path), f"empty file (0 bytes); {when_empty}")
    with open(path, "rb") as f:
        head = f.read(len(MAGIC))
    if head != MAGIC:
        raise RecordingError(str(path), f"not an MCAP file (starts with {head[:8]!r})")
    return size


def check_file(path: Path) -> None:
    """Raise :class:`RecordingError` unless ``path`` looks like a complete MCAP file."""
    size = check_head(path)
    with open(path, "rb") as f:
        f.seek(max(size - len(MAGIC), 0))
        tail = f.read(len(MAGIC))
    if size < 2 * len(MAGIC) + 9 or tail != MAGIC:
        raise RecordingError(
            str(path),
            f"truncated MCAP file ({size} bytes, no footer): the recording did not finish; "
            f"`formation recover {path}` writes a clean file from its complete chunks",
        )


def parts(path: Path) -> list[Path]:
    """``path`` and the files a rotating recorder continued it in (``run-001.mcap``, ...)."""
    found = [path]
    while (nxt := rotated_path(path, len(found))).exists():
        found.append(nxt)
    return found


@contextmanager
def open_recording(path: Path) -> Iterator[tuple[McapReader, Summary]]:
    """A seeking reader and the summary of a complete recording."""
    check_file(path)
    with open(path, "rb") as f:
        try:
            reader = make_reader(f)
            summary = reader.get_summary()
        except READ_ERRORS as exc:
            raise RecordingError(str(path), f"cannot read the MCAP summary ({exc})") from None
        if summary is None:
            raise RecordingError(str(path), "the MCAP file has no summary section")
        yield reader, summary


def iter_messages(
    path: Path, reader: McapReader, by_chunk: bool = True, **kwargs: Any
) -> Iterator[tuple[Schema | None, Channel, Message]]:
    """``reader.iter_messages(**kwargs)`` with read failures turned into :class:`RecordingError`;
    in file order (``log_time_order=False`` alone) a chunk at a time
    (:func:`~recorder.reading.chunks.file_order`) unless not ``by_chunk``."""
    try:
        summary = reader.get_summary()
        in_file_order = kwargs == {"log_time_order": False} and by_chunk
        if in_file_order and summary is not None and summary.chunk_indexes:
            yield from file_order(path, summary)
        else:
            yield from reader.iter_messages(**kwargs)
    except READ_ERRORS as exc:
        if isinstance(exc, TestbedError):
            raise
        raise RecordingError(str(path), f"unreadable data ({type(exc).__name__}: {exc})") from None


@contextmanager
def open_whole(path: Path) -> Iterator[tuple[IO[bytes], Summary, dict[str, dict[str, str]]]]:
    """The open file, summary and metadata of a complete recording to read whole, a chunk at
    a time (its chunk indexes without their per-channel offsets:
    :mod:`recorder.reading.summary`)."""
    check_file(path)
    with open(path, "rb") as f:
        try:
            summary = read_summary(f)
            meta = None if summary is None else read_metadata(f, summary)
        except READ_ERRORS as exc:
            raise RecordingError(str(path), f"cannot read the MCAP summary ({exc})") from None
        if summary is None or meta is None:
            raise RecordingError(str(path), "the MCAP file has no summary section")
        yield f, summary, meta


def iter_chunks(path: Path, f: IO[bytes], summary: Summary) -> Iterator[list[Record]]:
    """The message records of each chunk (:func:`~recorder.reading.chunks.file_chunks`) of
    the recording open as ``f`` (:func:`open_whole`), in file order, with read failures
    turned into :class:`RecordingError`."""
    try:
        if summary.chunk_indexes:
            yield from file_chunks(path, summary)
        else:  # no chunk index: the mcap reader's own loop, as records
            f.seek(0)
            for _, _, m in make_reader(f).iter_messages(log_time_order=False):
                yield [(m.channel_id, m.sequence, m.log_time, m.publish_time, m.data)]
    except READ_ERRORS as exc:
        if isinstance(exc, TestbedError):
            raise
        raise RecordingError(str(path), f"unreadable data ({type(exc).__name__}: {exc})") from None


def metadata(reader: McapReader) -> dict[str, dict[str, str]]:
    """Metadata records by name (a later record of the same name wins)."""
    return {m.name: dict(m.metadata) for m in reader.iter_metadata()}


@dataclass
class ChannelInfo:
    topic: str
    schema: str
    kind: str
    messages: int


@dataclass
class RecordingInfo:
    """What ``formation info`` prints about a recording."""

    path: Path
    size_bytes: int
    start_ns: int
    end_ns: int
    messages: int
    chunks: int
    compression: str
    channels: list[ChannelInfo]
    metadata: dict[str, dict[str, str]]
    scenario: Scenario | None
    sent: Counter[str] = field(default_factory=Counter)  # per link: packets netem decided on
    drops: Counter[str] = field(default_factory=Counter)  # per link: verdict drop
    skipped: Skipped = field(
        default_factory=Skipped
    )  # messages not trusted (recorder.reading.trust)

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / 1e9


def link_name(decision: dict[str, Any]) -> str:
    """``"formation 1->2"``, ``"report 3->0"``: a netem decision's link."""
    return f"{decision['link_class']} {decision['source']}->{decision['target']}"


def _count_drops(batch: DecisionBatch, sent: Counter[str], drops: Counter[str]) -> None:
    """Count a batch's records and drops per link (:func:`link_name`)."""
    cls, records = LINK_CLASS_OF[batch.phase], batch.records
    dropped = [j.verdict == "drop" for j in batch.judgements]
    for s, t, j in zip(records.source, records.target, records.judgement, strict=True):
        name = f"{cls} {s}->{t}"
        sent[name] += 1
        if dropped[j]:
            drops[name] += 1


def describe(path: Path) -> RecordingInfo:
    """Scenario, duration, channels with message counts, and netem's drops per link.

    Every message is checked (:class:`recorder.reading.trust.Gate`): the drops count only decisions
    that netem published and the scenario has, and ``skipped`` counts the rest per channel.
    """
    with open_recording(path) as (reader, summary):
        meta = metadata(reader)
        scenario = scenario_of(meta, path)
        gate = Gate(scenario, derived_channels(summary.channels))
        stats = summary.statistics
        counts = stats.channel_message_counts if stats else {}
        channels = []
        for cid, ch in sorted(summary.channels.items()):
            schema = summary.schemas.get(ch.schema_id)
            kind = ch.metadata.get("kind", classify(ch.topic))
            channels.append(
                ChannelInfo(ch.topic, schema.name if schema else "", kind, counts.get(cid, 0))
            )
        sent: Counter[str] = Counter()
        drops: Counter[str] = Counter()
        for _, ch, msg in iter_messages(path, reader, log_time_order=False):
            kind = ch.metadata.get("kind", classify(ch.topic))
            checked = gate.check(ch.topic, msg.data, kind, ch.id)
            if kind == "decision" and isinstance(checked, DecisionBatch):
                _count_drops(checked, sent, drops)
        comp = {c.compression or "none" for c in summary.chunk_indexes}
        return RecordingInfo(
            path=path,
            size_bytes=path.stat().st_size,
            start_ns=stats.message_start_time if stats else 0,
            end_ns=stats.message_end_time if stats else 0,
            messages=stats.message_count if stats else 0,
            chunks=len(summary.chunk_indexes),
            compression=",".join(sorted(comp)) or "-",
            channels=channels,
            metadata=meta,
            scenario=scenario,
            sent=sent,
            drops=drops,
            skipped=gate.skipped,
        )


@dataclass
class Validation:
    """Messages checked against their channel's stored schema, and the failures."""

    checked: int = 0
    failures: int = 0
    examples: list[tuple[str, int, str]] = field(default_factory=list)  # topic, log time, problem
    by_schema: Counter[str] = field(default_factory=Counter)


def validate(path: Path, limit: int = 20) -> Validation:
    """Check every message against the schema stored in its channel's schema record: JSON
    Schema for JSON, the FileDescriptorSet for protobuf, the ROS 2 type for CDR (it must decode)."""
    out = Validation()
    validators: dict[int, Any] = {}
    with open_recording(path) as (reader, _):
        for schema, channel, msg in iter_messages(path, reader, log_time_order=False):
            out.checked += 1
            name = schema.name if schema else "(none)"
            out.by_schema[name] += 1
            if schema is not None and schema.encoding == ROS2MSG:  # an agent's body traffic
                try:
                    decode_cdr(schema.name, msg.data)
                    continue
                except DecodeError as exc:
                    problem = f"{name}: not CDR ({exc})"
            elif schema is not None and schema.encoding == PROTOBUF:
                try:
                    decode(schema.name, schema.data, msg.data)
                    continue
                except DecodeError as exc:
                    problem = f"{name}: not protobuf ({exc})"
            else:
                check = validators.get(channel.schema_id)
                if check is None:
                    doc = json.loads(schema.data) if schema and schema.data else {}
                    check = validators[channel.schema_id] = validator_for(doc)(doc)
                try:
                    instance = json.loads(msg.data)
                except ValueError as exc:
                    problem = f"not JSON ({exc})"
                else:
                    error = next(iter(check.iter_errors(instance)), None)
                    if error is None:
                        continue
                    problem = f"{name}: {error.message} at {list(error.absolute_path)}"
            out.failures += 1
            if len(out.examples) < limit:
                out.examples.append((channel.topic, msg.log_time, problem))
    return out


__all__ = [
    "ChannelInfo",
    "RecordingInfo",
    "Validation",
    "check_file",
    "describe",
    "iter_chunks",
    "iter_messages",
    "link_name",
    "metadata",
    "open_recording",
    "open_whole",
    "parts",
    "scenario_of",
    "validate",
]
