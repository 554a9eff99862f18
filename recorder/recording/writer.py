"""MCAP writing: one channel per key with its schema, chunk compression, rotation.

The hot path does one ``struct.pack`` and two list appends per message: message
records go into the open chunk as bytes, and the chunk's message indexes,
statistics and time range are computed with numpy when the chunk closes. Schema
and channel records are written outside chunks (before the first chunk that uses
them), so every complete chunk on disk can be read even if the process is
killed; the stream is flushed after every chunk, so a kill loses at most the open
chunk. The records other than messages and chunks come from :mod:`mcap.records`,
and the files are read back with the ``mcap`` library in the tests.
"""

from __future__ import annotations

import os
import struct
import time
import zlib
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import IO, Any

import lz4.frame
import numpy as np
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

from recorder.recording.schemas import (
    ORIGIN,
    RECORDER,
    SchemaSpec,
    classify,
    message_encoding,
    schema_for_kind,
)

MAGIC = b"\x89MCAP0\r\n"
LIBRARY = "formation-recorder"
COMPRESSIONS = ("zstd", "lz4", "none")

_MESSAGE = struct.Struct("<BQHIQQ")  # opcode, length, channel id, sequence, log time, publish time
_HEAD = np.dtype(
    {
        "names": ["length", "channel", "log_time"],
        "formats": ["<u8", "<u2", "<u8"],
        "offsets": [1, 9, 15],
        "itemsize": _MESSAGE.size,
    }
)
_SEQ = struct.Struct("<8xq8x")  # seq of a codec attachment (epoch, seq, source)
_CHUNK = struct.Struct("<BQQQQI")  # opcode, length, start, end, uncompressed size, crc
_INDEX = struct.Struct("<BQHI")  # opcode, length, channel id, records length
_U32, _U64 = struct.Struct("<I"), struct.Struct("<Q")
_MASK32 = 0xFFFFFFFF

# One received sample: key, payload, attachment, zenoh timestamp (or None), receive time [ns].
Raw = tuple[str, bytes, "bytes | None", Any, int]


def _compressor(name: str) -> Callable[[bytes], bytes]:
    if name == "zstd":
        return zstandard.ZstdCompressor(level=3).compress
    if name == "lz4":
        return lz4.frame.compress  # type: ignore[no-any-return]
    if name == "none":
        return bytes
    raise ValueError(f"compression {name!r}; expected one of {', '.join(COMPRESSIONS)}")


class McapFile:
    """One MCAP file written chunk by chunk; messages are appended to :attr:`parts`."""

    def __init__(self, out: IO[bytes], compression: str = "zstd", close_stream: bool = False):
        self._out, self._close_stream = out, close_stream
        self._compress = _compressor(compression)
        self._compression = "" if compression == "none" else compression
        self.position = out.tell()
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self._chunk_indexes: list[ChunkIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self.counts: dict[int, int] = {}
        self.message_count = self.chunk_count = self.metadata_count = 0
        self.start_time, self.end_time = 0, 0
        self.parts: list[bytes] = []  # open chunk: header, payload, header, payload, ...
        self.size = 0  # bytes of message records in the open chunk
        self._raw(MAGIC)
        self._record(Header(profile="", library=LIBRARY))

    def _raw(self, data: bytes) -> None:
        self._out.write(data)
        self.position += len(data)

    def _record(self, record: Any) -> int:
        """Write a record from :mod:`mcap.records` outside any chunk; returns its offset."""
        builder: Any = RecordBuilder()  # untyped in mcap
        record.write(builder)
        offset = self.position
        self._raw(builder.end())
        return offset

    def add_schema(self, schema_id: int, spec: SchemaSpec) -> None:
        schema = Schema(id=schema_id, name=spec.name, encoding=spec.encoding, data=spec.data)
        self.schemas[schema_id] = schema
        self._record(schema)

    def add_channel(self, channel: Channel) -> None:
        self.channels[channel.id] = channel
        self._record(channel)

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        builder: Any = RecordBuilder()
        Metadata(name=name, metadata=dict(data)).write(builder)
        offset = self.position
        self._raw(builder.end())
        self._metadata_indexes.append(MetadataIndex(offset, self.position - offset, name))
        self.metadata_count += 1

    def add(self, channel_id: int, log_time: int, data: bytes, publish_time: int, seq: int) -> None:
        """Append one message to the open chunk (the batch path inlines this)."""
        self.parts += (
            _MESSAGE.pack(5, 22 + len(data), channel_id, seq, log_time, publish_time),
            data,
        )
        self.size += _MESSAGE.size + len(data)

    def close_chunk(self) -> None:
        """Compress the open chunk, write it with its message indexes, and flush the stream."""
        parts = self.parts
        k = len(parts) // 2
        if k == 0:
            return
        body = b"".join(parts)
        heads = np.frombuffer(b"".join(parts[0::2]), dtype=_HEAD)
        parts.clear()
        self.size = 0
        sizes = heads["length"] + np.uint64(9)
        offsets = np.zeros(k, dtype="<u8")
        np.cumsum(sizes[:-1], out=offsets[1:])
        chans, times = heads["channel"], heads["log_time"]
        start, end = int(times.min()), int(times.max())
        data = self._compress(body)
        comp = self._compression.encode()
        chunk_start = self.position
        length = 8 + 8 + 8 + 4 + 4 + len(comp) + 8 + len(data)
        head = _CHUNK.pack(Opcode.CHUNK, length, start, end, len(body), zlib.crc32(body))
        self._raw(b"".join((head, _U32.pack(len(comp)), comp, _U64.pack(len(data)))))
        self._raw(data)
        chunk_length = self.position - chunk_start
        order = np.lexsort((times, chans))
        chans_sorted = chans[order]
        cuts = np.flatnonzero(np.diff(chans_sorted)) + 1
        index_offsets: dict[int, int] = {}
        index_start = self.position
        pairs = np.empty((k, 2), dtype="<u8")
        pairs[:, 0], pairs[:, 1] = times[order], offsets[order]
        for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, k], strict=True):
            channel = int(chans_sorted[lo])
            records = pairs[lo:hi].tobytes()
            index_offsets[channel] = self.position
            self._raw(_INDEX.pack(Opcode.MESSAGE_INDEX, 6 + len(records), channel, len(records)))
            self._raw(records)
            self.counts[channel] = self.counts.get(channel, 0) + int(hi - lo)
        self._chunk_indexes.append(
            ChunkIndex(
                message_start_time=start,
                message_end_time=end,
                chunk_start_offset=chunk_start,
                chunk_length=chunk_length,
                message_index_offsets=index_offsets,
                message_index_length=self.position - index_start,
                compression=self._compression,
                compressed_size=len(data),
                uncompressed_size=len(body),
            )
        )
        self.start_time = start if self.message_count == 0 else min(self.start_time, start)
        self.end_time = max(self.end_time, end)
        self.message_count += k
        self.chunk_count += 1
        self._out.flush()

    def open_chunk_counts(self) -> dict[int, int]:
        """Messages per channel id in the open chunk (not yet on disk)."""
        if not self.parts:
            return {}
        chans = np.frombuffer(b"".join(self.parts[0::2]), dtype=_HEAD)["channel"]
        ids, counts = np.unique(chans, return_counts=True)
        return {int(i): int(c) for i, c in zip(ids, counts, strict=True)}

    def fsync(self) -> None:
        self._out.flush()
        if hasattr(self._out, "fileno"):
            os.fsync(self._out.fileno())

    def finish(self) -> None:
        """Close the open chunk and write the summary (schemas, channels, statistics, indexes)."""
        self.close_chunk()
        self._record(DataEnd(data_section_crc=0))
        summary_start = self.position
        builder: Any = RecordBuilder()
        offsets: list[SummaryOffset] = []
        groups: list[tuple[Opcode, Iterable[Any]]] = [
            (Opcode.SCHEMA, self.schemas.values()),
            (Opcode.CHANNEL, self.channels.values()),
            (Opcode.STATISTICS, [self._statistics()]),
            (Opcode.CHUNK_INDEX, self._chunk_indexes),
            (Opcode.METADATA_INDEX, self._metadata_indexes),
        ]
        for opcode, records in groups:
            begin = builder.count
            for record in records:
                record.write(builder)
            if builder.count > begin:
                offsets.append(SummaryOffset(opcode, summary_start + begin, builder.count - begin))
        offset_start = summary_start + builder.count
        for summary_offset in offsets:
            summary_offset.write(builder)
        summary = builder.end()
        footer_head = struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, offset_start)
        crc = zlib.crc32(footer_head, zlib.crc32(summary))
        self._raw(summary)
        self._record(Footer(summary_start, offset_start, crc))
        self._raw(MAGIC)
        self._out.flush()
        if self._close_stream:
            self._out.close()

    def _statistics(self) -> Statistics:
        return Statistics(
            message_count=self.message_count,
            schema_count=len(self.schemas),
            channel_count=len(self.channels),
            attachment_count=0,
            metadata_count=self.metadata_count,
            chunk_count=self.chunk_count,
            message_start_time=self.start_time,
            message_end_time=self.end_time,
            channel_message_counts=dict(self.counts),
        )


def rotated_path(path: Path, index: int) -> Path:
    """``run.mcap``, ``run-001.mcap``, ``run-002.mcap``, ...: file ``index`` of a rotated recording."""
    return path if index == 0 else path.with_name(f"{path.stem}-{index:03d}{path.suffix}")


class RecordingWriter:
    """A recording of keyed payloads into one MCAP file or a rotated series of them.

    Channels are created on first sight of a key and keep their ids across files;
    every file repeats the schemas, the channels and the sticky metadata (the scenario).
    """

    def __init__(
        self,
        path: Path | IO[bytes],
        *,
        compression: str = "zstd",
        chunk_size: int = 1 << 20,
        chunk_interval_s: float = 0.5,
        split_size: int | None = None,
        split_duration_s: float | None = None,
        fsync_interval_s: float | None = 1.0,
        metadata: Mapping[str, Mapping[str, str]] | None = None,
        taps: Iterable[str] = (),
    ) -> None:
        _compressor(compression)  # reject a bad name before a file exists
        self.path = path if isinstance(path, Path) else None
        self._stream = None if isinstance(path, Path) else path
        self.compression, self.chunk_size = compression, chunk_size
        self.chunk_interval_ns = int(chunk_interval_s * 1e9)
        self.split_size, self.split_duration_s = split_size, split_duration_s
        self.fsync_interval_ns = None if fsync_interval_s is None else int(fsync_interval_s * 1e9)
        self._sticky = {name: dict(data) for name, data in (metadata or {}).items()}
        self._taps = frozenset(taps)
        self.ids: dict[str, int] = {}
        self._derived_ids: dict[str, int] = {}  # the recorder's own messages (metrics, scene)
        self.derived: set[int] = set()
        self.topics: dict[int, str] = {}
        self.kinds: dict[int, str] = {}
        self._tapped: dict[int, str] = {}
        self._schema_ids: dict[str, int] = {}
        self._schemas: dict[int, SchemaSpec] = {}
        self._closed_counts: dict[int, int] = {}
        self.files: list[Path] = []
        self._chunk_opened: int | None = None
        self._last_fsync = time.monotonic_ns()
        self._file = self._open_file()

    # -- files ----------------------------------------------------------------------------
    def _open_file(self) -> McapFile:
        if self.path is None:
            assert self._stream is not None
            f = McapFile(self._stream, self.compression)
        else:
            target = rotated_path(self.path, len(self.files))
            target.parent.mkdir(parents=True, exist_ok=True)
            f = McapFile(open(target, "wb"), self.compression, close_stream=True)  # noqa: SIM115
            self.files.append(target)
        self._file_opened = time.monotonic_ns()
        for name, data in self._sticky.items():
            f.add_metadata(name, data)
        for schema_id, spec in self._schemas.items():
            f.add_schema(schema_id, spec)
        for cid, topic in self.topics.items():
            f.add_channel(self._channel_record(cid, topic))
        return f

    def _channel_record(self, cid: int, topic: str) -> Channel:
        metadata = {"kind": self.kinds[cid]}
        if cid in self.derived:
            metadata[ORIGIN] = RECORDER
        return Channel(
            id=cid,
            topic=topic,
            message_encoding=message_encoding(self.kinds[cid]),
            schema_id=self._schema_ids[schema_for_kind(self.kinds[cid]).name],
            metadata=metadata,
        )

    def _rotate(self) -> None:
        if self.path is None:
            return  # a stream cannot be split
        self._finish_file()
        self._file = self._open_file()

    def _finish_file(self) -> None:
        f = self._file
        f.finish()
        for cid, count in f.counts.items():
            self._closed_counts[cid] = self._closed_counts.get(cid, 0) + count

    # -- channels -------------------------------------------------------------------------
    def channel(self, key: str, derived: bool = False) -> int:
        """The channel id of ``key``, registering its schema and channel on first use.

        ``derived``: the channel of what the recorder itself writes on ``key`` (metadata
        ``origin = recorder``), apart from what arrived on that key over Zenoh, so that
        a reader can tell the recorder's metrics and scenes from forged ones.
        """
        ids = self._derived_ids if derived else self.ids
        cid = ids.get(key)
        if cid is not None:
            return cid
        kind = classify(key)
        spec = schema_for_kind(kind)
        if spec.name not in self._schema_ids:
            schema_id = len(self._schema_ids) + 1
            self._schema_ids[spec.name], self._schemas[schema_id] = schema_id, spec
            self._file.add_schema(schema_id, spec)
        cid = len(self.topics) + 1
        ids[key], self.topics[cid], self.kinds[cid] = cid, key, kind
        if derived:
            self.derived.add(cid)
        elif kind in self._taps:
            self._tapped[cid] = kind
        self._file.add_channel(self._channel_record(cid, key))
        return cid

    # -- messages -------------------------------------------------------------------------
    def write_batch(self, batch: Sequence[Raw]) -> list[tuple[str, str, bytes, int]]:
        """Write received samples in order; returns ``(kind, key, payload, recv_ns)`` of tapped kinds."""
        tapped: list[tuple[str, str, bytes, int]] = []
        start = 0
        while start < len(batch):
            start = self._fill(batch, start, tapped)
            if self._file.size >= self.chunk_size:
                self._close_chunk()
        return tapped

    def _fill(
        self, batch: Sequence[Raw], start: int, tapped: list[tuple[str, str, bytes, int]]
    ) -> int:
        f, ids, taps, limit = self._file, self.ids, self._tapped, self.chunk_size
        parts, pack, seq_of, size = f.parts, _MESSAGE.pack, _SEQ.unpack, f.size
        for j in range(start, len(batch)):
            key, data, att, ts, recv = batch[j]
            cid = ids.get(key)
            if cid is None:
                cid = self.channel(key)
            if cid in taps:
                tapped.append((taps[cid], key, data, recv))
            seq = 0 if att is None or len(att) != _SEQ.size else seq_of(att)[0] & _MASK32
            pub = recv if ts is None else ts.get_time_as_ntp64().as_nanos()
            parts += (pack(5, 22 + len(data), cid, seq, recv, pub), data)
            size += 31 + len(data)
            if size >= limit:
                f.size = size
                return j + 1
        f.size = size
        return len(batch)

    def write(self, key: str, data: bytes, log_time: int) -> None:
        """Write one message the recorder made itself (metrics, scene); publish time = log time."""
        self._file.add(self.channel(key, derived=True), log_time, data, log_time, 0)
        if self._file.size >= self.chunk_size:
            self._close_chunk()

    def _close_chunk(self) -> None:
        self._file.close_chunk()
        self._chunk_opened = None
        if self.split_size is not None and self._file.position >= self.split_size:
            self._rotate()

    def tick(self, now_ns: int) -> None:
        """Time-driven work: close a chunk open too long, rotate by duration, fsync."""
        if self._file.parts:
            if self._chunk_opened is None:
                self._chunk_opened = now_ns
            elif now_ns - self._chunk_opened >= self.chunk_interval_ns:
                self._close_chunk()
        if (
            self.split_duration_s is not None
            and now_ns - self._file_opened >= self.split_duration_s * 1e9
        ):
            self._close_chunk()
            self._rotate()
        if (
            self.fsync_interval_ns is not None
            and now_ns - self._last_fsync >= self.fsync_interval_ns
        ):
            self._file.fsync()
            self._last_fsync = now_ns

    def add_metadata(self, name: str, data: Mapping[str, str], sticky: bool = False) -> None:
        """Metadata in the current file; ``sticky`` metadata is repeated in every later file."""
        if sticky:
            self._sticky[name] = dict(data)
        self._file.add_metadata(name, data)

    def counts(self) -> dict[str, int]:
        """Messages per key so far, including the open chunk."""
        total = dict(self._closed_counts)
        for source in (self._file.counts, self._file.open_chunk_counts()):
            for cid, count in source.items():
                total[cid] = total.get(cid, 0) + count
        out: dict[str, int] = {}
        for cid, count in sorted(total.items()):
            topic = self.topics[cid]
            out[topic] = out.get(topic, 0) + count
        return out

    def close(self) -> list[Path]:
        """Finish the current file (summary, indexes, footer); returns every file written."""
        self._finish_file()
        return list(self.files)


__all__ = ["COMPRESSIONS", "MAGIC", "McapFile", "Raw", "RecordingWriter", "rotated_path"]
