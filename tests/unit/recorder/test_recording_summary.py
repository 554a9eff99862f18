"""A recording's summary read to read it whole: the library's summary without the chunk
indexes' per-channel offsets, and a broken one named as the file's error."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from mcap.summary import Summary

from formation.errors import RecordingError
from recorder import load_run
from recorder.reading.reader import metadata
from recorder.reading.summary import read_metadata, read_summary


def _library(path: Path) -> tuple[Summary, dict[str, dict[str, str]]]:
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        return summary, metadata(reader)


def test_the_summary_is_the_library_s_without_the_chunks_channel_offsets(
    tmp_path: Path, sim_results: dict[str, Any], synth: Any
) -> None:
    path = tmp_path / "run.mcap"
    synth.write(path, sim_results["hold"])
    theirs, their_meta = _library(path)
    with open(path, "rb") as f:
        ours = read_summary(f)
        assert ours is not None
        assert read_metadata(f, ours) == their_meta
    assert ours.channels == theirs.channels and ours.schemas == theirs.schemas
    assert ours.statistics == theirs.statistics
    assert ours.metadata_indexes == theirs.metadata_indexes
    assert len(ours.chunk_indexes) == len(theirs.chunk_indexes) > 1
    assert any(c.message_index_offsets for c in theirs.chunk_indexes)
    assert ours.chunk_indexes == [
        dataclasses.replace(c, message_index_offsets={}) for c in theirs.chunk_indexes
    ]


def test_a_chunk_index_past_its_record_is_the_file_s_error(
    tmp_path: Path, sim_results: dict[str, Any], synth: Any
) -> None:
    path = tmp_path / "run.mcap"
    synth.write(path, sim_results["hold"])
    theirs, _ = _library(path)
    data = bytearray(path.read_bytes())
    first = theirs.chunk_indexes[0]
    # the first chunk index's record: find it by its start time, offset and length
    head = b"".join(
        v.to_bytes(8, "little")
        for v in (
            first.message_start_time,
            first.message_end_time,
            first.chunk_start_offset,
            first.chunk_length,
        )
    )
    at = data.index(head) + len(head)
    data[at : at + 4] = (1 << 31).to_bytes(4, "little")  # offsets of 2 GB
    path.write_bytes(bytes(data))
    with pytest.raises(RecordingError, match=r"run\.mcap.*chunk index's offsets"):
        load_run(path)
