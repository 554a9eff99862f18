"""A recording's summary section for reading it whole: its chunk indexes without their
per-channel offsets.

A chunk index lists, for each channel with a message in the chunk, where that channel's
message index is; with a channel per agent a recording of 10,000 agents holds a million such
entries, which the mcap reader parses one at a time, only to find the messages of chosen
topics. Reading every chunk in order needs none of them: here each chunk index is read with
one ``struct`` call and its offsets skipped (``message_index_offsets`` left empty, which the
library takes as "unknown"); every other summary record is read by the library (the record
layout of the MCAP specification).
"""

from __future__ import annotations

import io
import struct
from collections.abc import Callable
from typing import IO, Any

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import (
    AttachmentIndex,
    Channel,
    ChunkIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
)
from mcap.summary import Summary

_RECORD = struct.Struct("<BQ")  # opcode, length
_FOOTER = struct.Struct("<BQQQI")  # opcode, length, summary start, summary offset start, crc
_MAGIC = 8
_CHUNK_HEAD = struct.Struct("<QQQQI")  # start and end time, offset, length, offsets' bytes
_INDEX_LENGTH = struct.Struct("<QI")  # message index length, compression's bytes
_SIZES = struct.Struct("<QQ")  # compressed and uncompressed size
_READ: dict[int, Callable[[ReadDataStream], Any]] = {
    Opcode.SCHEMA: Schema.read,
    Opcode.CHANNEL: Channel.read,
    Opcode.STATISTICS: Statistics.read,
    Opcode.METADATA_INDEX: MetadataIndex.read,
    Opcode.ATTACHMENT_INDEX: AttachmentIndex.read,
}


class SummaryError(Exception):
    """A summary section whose records do not fit its bytes."""


def read_summary(f: IO[bytes]) -> Summary | None:
    """The summary of the complete recording open as ``f``, chunk indexes without their
    per-channel offsets; None if it has no summary section."""
    end = f.seek(0, io.SEEK_END)
    footer_at = end - _FOOTER.size - _MAGIC
    f.seek(footer_at)
    opcode, _, summary_start, _, _ = _FOOTER.unpack(f.read(_FOOTER.size))
    if opcode != Opcode.FOOTER:
        raise SummaryError(f"no footer record at byte {footer_at} (opcode {opcode})")
    if summary_start == 0:
        return None
    if not 0 < summary_start <= footer_at:
        raise SummaryError(f"a summary starting at byte {summary_start} of {end}")
    f.seek(summary_start)
    data = f.read(footer_at - summary_start)
    summary, pos = Summary(), 0
    while pos < len(data):
        if pos + _RECORD.size > len(data):
            raise SummaryError(f"a record header cut at byte {summary_start + pos}")
        opcode, length = _RECORD.unpack_from(data, pos)
        start, pos = pos + _RECORD.size, pos + _RECORD.size + length
        if pos > len(data):
            raise SummaryError(f"a record of {length} bytes at byte {summary_start + start}")
        if opcode == Opcode.CHUNK_INDEX:
            summary.chunk_indexes.append(_chunk_index(data, start, pos))
        elif opcode in _READ:
            _add(summary, _READ[opcode](ReadDataStream(io.BytesIO(data[start:pos]))))
    return summary


def _chunk_index(data: bytes, at: int, end: int) -> ChunkIndex:
    start_time, end_time, offset, length, skipped = _CHUNK_HEAD.unpack_from(data, at)
    at += _CHUNK_HEAD.size + skipped
    if at + _INDEX_LENGTH.size > end:
        raise SummaryError(f"a chunk index's offsets of {skipped} bytes past its record")
    index_length, name_length = _INDEX_LENGTH.unpack_from(data, at)
    at += _INDEX_LENGTH.size
    if at + name_length + _SIZES.size > end:
        raise SummaryError(f"a chunk index's compression of {name_length} bytes past its record")
    compression = data[at : at + name_length].decode()
    compressed, uncompressed = _SIZES.unpack_from(data, at + name_length)
    return ChunkIndex(
        message_start_time=start_time,
        message_end_time=end_time,
        chunk_start_offset=offset,
        chunk_length=length,
        message_index_offsets={},
        message_index_length=index_length,
        compression=compression,
        compressed_size=compressed,
        uncompressed_size=uncompressed,
    )


def _add(summary: Summary, record: Any) -> None:
    if isinstance(record, Schema):
        summary.schemas[record.id] = record
    elif isinstance(record, Channel):
        summary.channels[record.id] = record
    elif isinstance(record, Statistics):
        summary.statistics = record
    elif isinstance(record, MetadataIndex):
        summary.metadata_indexes.append(record)
    else:
        summary.attachment_indexes.append(record)


def read_metadata(f: IO[bytes], summary: Summary) -> dict[str, dict[str, str]]:
    """The metadata records that ``summary`` indexes, by name (a later one of a name wins)."""
    out: dict[str, dict[str, str]] = {}
    for index in summary.metadata_indexes:
        f.seek(index.offset)
        opcode, _ = _RECORD.unpack(f.read(_RECORD.size))
        if opcode != Opcode.METADATA:
            raise SummaryError(f"no metadata record at byte {index.offset} (opcode {opcode})")
        record = Metadata.read(ReadDataStream(f))
        out[record.name] = dict(record.metadata)
    return out


__all__ = ["SummaryError", "read_metadata", "read_summary"]
