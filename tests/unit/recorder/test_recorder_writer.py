"""MCAP writing: round trips through BytesIO and files, read back with the mcap library."""

from __future__ import annotations

import io
import json
import struct
import zlib
from pathlib import Path

import pytest
import zstandard
from foxglove.messages import SceneUpdate
from mcap.exceptions import EndOfFile
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Chunk, Message, MessageIndex
from mcap.stream_reader import StreamReader

from formation import keys
from formation.codec import attachment
from recorder.reading.decoder import decode_kind
from recorder.recording.schemas import foxglove_schema
from recorder.recording.writer import RecordingWriter, rotated_path

RUN = "r1"
KEYS = [keys.agent_state(RUN, 1), keys.agent_state(RUN, 2), keys.netem_decision(RUN), "elsewhere/x"]


def batch(count: int, start: int = 0) -> list[tuple[str, bytes, bytes | None, None, int]]:
    """``count`` samples round-robin over :data:`KEYS`; seq ``k`` in the attachment, log time 1000 + k."""
    out = []
    for k in range(start, start + count):
        key = KEYS[k % len(KEYS)]
        att = attachment(7, k, 1) if k % 3 else None
        out.append((key, json.dumps({"k": k, "pad": "x" * (k % 17)}).encode(), att, None, 1000 + k))
    return out


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_round_trip_through_bytesio(compression: str) -> None:
    buf = io.BytesIO()
    rec = RecordingWriter(
        buf, compression=compression, chunk_size=2048, metadata={"scenario": {"toml": "a = 1"}}
    )
    sent = batch(500)
    rec.write_batch(sent)
    rec.write(keys.metrics(RUN), b'{"m": 1}', 99_999)
    rec.close()

    buf.seek(0)
    reader = make_reader(buf, validate_crcs=True)
    summary = reader.get_summary()
    assert summary is not None and summary.statistics is not None
    assert summary.statistics.message_count == 501
    assert len(summary.chunk_indexes) > 5
    assert {c.compression for c in summary.chunk_indexes} == {
        "" if compression == "none" else compression
    }
    got = list(reader.iter_messages(log_time_order=False))
    assert len(got) == 501
    for (key, data, att, _, log_time), (schema, channel, msg) in zip(sent, got, strict=False):
        assert channel.topic == key
        assert channel.message_encoding == "json"
        assert msg.data == data and msg.log_time == log_time and msg.publish_time == log_time
        assert msg.sequence == (struct.unpack("<qqq", att)[1] if att else 0)
        assert schema is not None and schema.encoding == "jsonschema"
    names = {ch.topic: summary.schemas[ch.schema_id].name for ch in summary.channels.values()}
    assert names[keys.agent_state(RUN, 1)] == "formation.CoordinationState"
    assert names[keys.netem_decision(RUN)] == "formation.DecisionBatch"
    assert names["elsewhere/x"] == "unknown"
    assert names[keys.metrics(RUN)] == "formation.EpochMetrics"
    unknown = next(s for s in summary.schemas.values() if s.name == "unknown")
    assert unknown.data == b"{}"
    counts = summary.statistics.channel_message_counts
    assert sum(counts.values()) == 501
    assert [m.name for m in reader.iter_metadata()] == ["scenario"]


def test_every_message_index_points_at_its_message() -> None:
    buf = io.BytesIO()
    rec = RecordingWriter(buf, compression="zstd", chunk_size=4096)
    rec.write_batch(batch(300))
    rec.close()
    buf.seek(0)
    records = list(StreamReader(buf, emit_chunks=True, validate_crcs=True).records)
    chunk = None
    checked = 0
    for record in records:
        if isinstance(record, Chunk):
            chunk = record
            body = zstandard.ZstdDecompressor().decompress(
                chunk.data, max_output_size=chunk.uncompressed_size
            )
            assert zlib.crc32(body) == chunk.uncompressed_crc
        elif isinstance(record, MessageIndex):
            assert chunk is not None
            times = [t for t, _ in record.records]
            assert times == sorted(times)
            for log_time, offset in record.records:
                opcode, _ = struct.unpack_from("<BQ", body, offset)
                channel, _, msg_time = struct.unpack_from("<HIQ", body, offset + 9)
                assert (opcode, channel, msg_time) == (5, record.channel_id, log_time)
                checked += 1
    assert checked == 300


def test_stream_and_non_seeking_readers_agree() -> None:
    buf = io.BytesIO()
    rec = RecordingWriter(buf, chunk_size=1000)
    rec.write_batch(batch(200))
    rec.close()
    buf.seek(0)
    streamed = [r for r in StreamReader(buf, validate_crcs=True).records if isinstance(r, Message)]
    buf.seek(0)
    linear = [m for _, _, m in NonSeekingReader(buf).iter_messages(log_time_order=False)]
    assert streamed == linear and len(linear) == 200


def readable_messages(data: bytes) -> list[Message]:
    """The messages of a file that may end without a footer (read until the stream ends)."""
    got: list[Message] = []
    try:
        for record in StreamReader(io.BytesIO(data)).records:
            if isinstance(record, Message):
                got.append(record)
    except EndOfFile:
        pass
    return got


def test_a_chunk_open_too_long_is_written_on_tick() -> None:
    buf = io.BytesIO()
    rec = RecordingWriter(buf, chunk_size=1 << 20, chunk_interval_s=0.5, fsync_interval_s=None)
    rec.write_batch(batch(10))
    rec.tick(0)  # the chunk is first seen open now
    rec.tick(400_000_000)
    assert readable_messages(buf.getvalue()) == []
    rec.tick(500_000_000)
    assert len(readable_messages(buf.getvalue())) == 10


def test_rotation_by_size_repeats_schemas_channels_and_scenario(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    meta = {"scenario": {"toml": "name = 'x'"}}
    rec = RecordingWriter(path, chunk_size=2000, split_size=6000, metadata=meta)
    sent = batch(1200)
    rec.write_batch(sent)
    files = rec.close()
    assert len(files) > 2
    assert files[:3] == [path, tmp_path / "run-001.mcap", tmp_path / "run-002.mcap"]
    assert rotated_path(path, 12) == tmp_path / "run-012.mcap"
    total = 0
    for file in files:
        with open(file, "rb") as f:
            reader = make_reader(f, validate_crcs=True)
            summary = reader.get_summary()
            assert summary is not None and summary.statistics is not None
            topics = {c.topic for c in summary.channels.values()}
            assert topics == set(KEYS)  # every channel known so far is in every file
            assert [m.metadata for m in reader.iter_metadata()] == [meta["scenario"]]
            total += sum(1 for _ in reader.iter_messages())
    assert total == len(sent)


def test_rotation_by_duration(tmp_path: Path) -> None:
    rec = RecordingWriter(tmp_path / "run.mcap", split_duration_s=1.0, fsync_interval_s=None)
    rec.write_batch(batch(10))
    rec.tick(rec._file_opened + 999_000_000)
    assert len(rec.files) == 1
    rec.tick(rec._file_opened + 1_000_000_000)
    rec.write_batch(batch(10, start=10))
    files = rec.close()
    assert len(files) == 2
    counts = []
    for file in files:
        with open(file, "rb") as f:
            counts.append(sum(1 for _ in make_reader(f).iter_messages()))
    assert counts == [10, 10]


def test_foxglove_channels_get_the_sdk_s_protobuf_schema() -> None:
    buf = io.BytesIO()
    rec = RecordingWriter(buf)
    rec.write(keys.scene(RUN), SceneUpdate().encode(), 5)
    rec.write(keys.frames(RUN), b"", 5)
    rec.write(keys.log(RUN), b"", 5)
    rec.write(keys.metrics(RUN), b"{}", 5)
    rec.close()
    buf.seek(0)
    reader = make_reader(buf)
    summary = reader.get_summary()
    assert summary is not None
    by_topic = {
        ch.topic: (ch.message_encoding, summary.schemas[ch.schema_id])
        for ch in summary.channels.values()
    }
    for key, kind in ((keys.scene(RUN), "scene"), (keys.frames(RUN), "tf"), (keys.log(RUN), "log")):
        encoding, schema = by_topic[key]
        assert (encoding, schema.encoding) == ("protobuf", "protobuf")
        assert (schema.name, schema.data) == (
            foxglove_schema(kind).name,
            foxglove_schema(kind).data,
        )
    assert by_topic[keys.metrics(RUN)][0] == "json"
    (_, _, msg), *_ = reader.iter_messages(topics=[keys.scene(RUN)])
    assert decode_kind("scene", msg.data).entities is not None


def test_live_counts_include_the_open_chunk() -> None:
    rec = RecordingWriter(io.BytesIO(), chunk_size=1500)
    rec.write_batch(batch(100))
    counts = rec.counts()
    assert sum(counts.values()) == 100
    assert counts[KEYS[0]] == 25
    assert json.loads(json.dumps(counts)) == counts  # plain ints: the flush queryable sends JSON


def test_unknown_compression_is_refused() -> None:
    with pytest.raises(ValueError, match="compression 'brotli'; expected one of zstd, lz4, none"):
        RecordingWriter(io.BytesIO(), compression="brotli")
