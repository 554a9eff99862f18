"""``formation recover``: a clean MCAP file from what a killed recorder left.

The recorder flushes after every chunk and writes schemas and channels outside
chunks, so a file cut anywhere holds a readable prefix: the header, then complete
chunks, then possibly a torn record. :class:`mcap.stream_reader.StreamReader`
yields records in file order (a chunk's messages only once the whole chunk has
been read and decompressed); the first record that fails ends the readable
prefix. Everything before it is rewritten with the same channel and schema ids,
a fresh summary and indexes.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mcap.records import Channel, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader

from formation.errors import RecordingError
from recorder.reading.reader import check_head
from recorder.recording.schemas import SchemaSpec
from recorder.recording.writer import MAGIC, McapFile

CHUNK_SIZE = 1 << 20  # [bytes] uncompressed, in the recovered file


@dataclass
class Recovered:
    """What :func:`recover` kept."""

    source: Path
    target: Path
    messages: int
    channels: int
    metadata: int
    readable_bytes: int  # the prefix of the source that was read
    source_bytes: int
    complete: bool  # the source had its footer: nothing was lost
    problem: str  # why reading stopped ("" when complete)

    def describe(self) -> str:
        lost = self.source_bytes - self.readable_bytes
        how = (
            "complete file"
            if self.complete
            else f"stopped at byte {self.readable_bytes} ({self.problem})"
        )
        return (
            f"{self.target}: kept {self.messages} messages on {self.channels} channels from {self.source}; "
            f"{how}; {lost} trailing bytes unreadable"
        )


def default_target(source: Path) -> Path:
    return source.with_name(f"{source.stem}-recovered{source.suffix}")


def recover(source: Path, target: Path | None = None, compression: str = "zstd") -> Recovered:
    """Copy every readable record of ``source`` into a finished MCAP file ``target``."""
    source = Path(source)
    target = Path(target) if target is not None else default_target(source)
    if source.resolve() == target.resolve():
        raise RecordingError(str(source), "recover needs a different output file (-o)")
    size = check_head(source, when_empty="nothing to recover")
    with open(source, "rb") as src, open(target, "wb") as dst:
        return _copy(src, McapFile(dst, compression), source, target, size)


def _copy(src: object, out: McapFile, source: Path, target: Path, size: int) -> Recovered:
    reader = StreamReader(src, validate_crcs=True)  # type: ignore[arg-type]
    messages = 0
    readable = len(MAGIC)
    problem = ""
    complete = False
    records = reader.records
    while True:
        try:
            record = next(records)
        except StopIteration:
            break
        except Exception as exc:
            problem = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
            break
        readable = src.tell()  # type: ignore[attr-defined]
        if isinstance(record, Schema):
            out.add_schema(record.id, SchemaSpec(record.name, record.encoding, record.data))
        elif isinstance(record, Channel):
            out.add_channel(record)
        elif isinstance(record, Metadata):
            out.add_metadata(record.name, record.metadata)
        elif isinstance(record, Message):
            if record.channel_id not in out.channels:
                continue  # its channel record was lost: the message cannot be decoded
            out.add(
                record.channel_id,
                record.log_time,
                record.data,
                record.publish_time,
                record.sequence,
            )
            messages += 1
            if out.size >= CHUNK_SIZE:
                out.close_chunk()
        elif isinstance(record, Footer):
            complete = True
            readable = size
            break
    out.finish()
    return Recovered(
        source=source,
        target=target,
        messages=messages,
        channels=len(out.channels),
        metadata=out.metadata_count,
        readable_bytes=readable,
        source_bytes=size,
        complete=complete,
        problem=problem,
    )


__all__ = ["Recovered", "default_target", "recover"]
