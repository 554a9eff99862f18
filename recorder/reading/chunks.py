"""A recording's messages in file order, a chunk at a time: the library's records, less Python per message.

The mcap reader builds a stream object per chunk and reads each record's fields through it;
a recording of 10,000 agents holds a million messages. Here each chunk is read and
decompressed by the library (:class:`mcap.records.Chunk`,
:func:`mcap.stream_reader.get_chunk_data_stream`) and its message records are cut out
of the bytes with one ``struct`` call each (the record layout of the MCAP specification).
The order is the reader's own with ``log_time_order=False``: chunks in the summary's
order, records in chunk order.
"""

from __future__ import annotations

import io
import struct
from collections.abc import Iterator
from pathlib import Path

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Message, Schema
from mcap.stream_reader import get_chunk_data_stream
from mcap.summary import Summary

_RECORD = struct.Struct("<BQ")  # opcode, length
_MESSAGE = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_MESSAGE_HEAD = _MESSAGE.size  # bytes before a message's data
_MESSAGE_RECORD = struct.Struct("<BQHIQQ")  # a message record up to its data
_CHUNK_SKIP = 1 + 8  # a chunk record's opcode and length


class ChunkError(Exception):
    """A chunk whose records do not fit its bytes, or a message on a channel the summary lacks."""


Record = tuple[int, int, int, int, bytes]  # channel id, sequence, log time, publish time, data


def chunk_messages(data: bytes) -> list[Record]:
    """``(channel id, sequence, log time, publish time, data)`` of each message record in a
    chunk's uncompressed ``data``; other records are skipped."""
    end, pos = len(data), 0
    unpack_record, unpack_message = _RECORD.unpack_from, _MESSAGE_RECORD.unpack_from
    head, message_head = _RECORD.size, _MESSAGE_RECORD.size
    message = Opcode.MESSAGE
    out: list[Record] = []
    add = out.append
    while pos < end:
        if pos + message_head <= end:  # a message's fields read with its header: one call
            opcode, length, channel_id, sequence, log_time, publish_time = unpack_message(data, pos)
        elif pos + head <= end:  # too short for a message: the message check below refuses it
            opcode, length = unpack_record(data, pos)
        else:
            raise ChunkError(f"a record header cut at byte {pos} of {end}")
        start, pos = pos, pos + head + length
        if pos > end:
            raise ChunkError(f"a record of {length} bytes at byte {start} of {end}")
        if opcode == message:
            if length < _MESSAGE_HEAD:
                raise ChunkError(f"a message record of {length} bytes")
            add((channel_id, sequence, log_time, publish_time, data[start + message_head : pos]))
    return out


def file_chunks(path: Path, summary: Summary) -> Iterator[list[Record]]:
    """The message records of each chunk of the complete recording at ``path``, a list a chunk,
    in the order ``McapReader.iter_messages(log_time_order=False)`` yields them."""
    channels = summary.channels
    zstd = zstandard.ZstdDecompressor()  # one per file: a decompressor is not thread-safe
    with open(path, "rb") as f:
        for index in summary.chunk_indexes:
            f.seek(index.chunk_start_offset + _CHUNK_SKIP, io.SEEK_SET)
            chunk = Chunk.read(ReadDataStream(f))
            if chunk.compression == "zstd":  # as the library does, without two copies
                data = zstd.decompress(chunk.data, max_output_size=chunk.uncompressed_size)
            else:
                stream, size = get_chunk_data_stream(chunk)
                data = stream.read(size)
            records = chunk_messages(data)
            for channel_id in {r[0] for r in records} - channels.keys():
                raise ChunkError(f"a message on channel {channel_id}, not in the summary")
            yield records


def file_order(path: Path, summary: Summary) -> Iterator[tuple[Schema | None, Channel, Message]]:
    """Every message in the chunks of the complete recording at ``path``, as
    ``McapReader.iter_messages(log_time_order=False)`` yields them."""
    channels, schemas = summary.channels, summary.schemas
    for records in file_chunks(path, summary):
        for channel_id, sequence, log_time, publish_time, data in records:
            channel = channels[channel_id]
            schema = schemas[channel.schema_id] if channel.schema_id else None
            yield (
                schema,
                channel,
                Message(
                    channel_id=channel_id,
                    log_time=log_time,
                    data=data,
                    publish_time=publish_time,
                    sequence=sequence,
                ),
            )


__all__ = ["ChunkError", "Record", "chunk_messages", "file_chunks", "file_order"]
