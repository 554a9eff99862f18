"""Recovery of a cut recording: every message of every complete chunk, nothing else."""

from __future__ import annotations

from pathlib import Path

import pytest
from mcap.reader import make_reader

from formation.errors import RecordingError
from recorder.reading.recovery import recover
from recorder.recording.writer import McapFile, RecordingWriter

N_CHUNKS, PER_CHUNK = 6, 40


def write_chunks(path: Path, compression: str) -> list[tuple[int, int]]:
    """A file of ``N_CHUNKS`` chunks; returns (end of chunk record, messages so far) per chunk.

    A chunk is complete when its record is: the message indexes after it are not needed.
    """
    marks = []
    rec = RecordingWriter(path, compression=compression, chunk_size=1 << 30, fsync_interval_s=None)
    f: McapFile = rec._file
    for c in range(N_CHUNKS):
        rec.write_batch(
            [
                (f"formation/r/agent/{k % 3 + 1}/state", b'{"k": %d}' % k, None, None, k)
                for k in range(c * PER_CHUNK, (c + 1) * PER_CHUNK)
            ]
        )
        f.close_chunk()
        index = f._chunk_indexes[-1]
        marks.append((index.chunk_start_offset + index.chunk_length, (c + 1) * PER_CHUNK))
    rec.close()
    return marks


def messages_in(path: Path) -> list[int]:
    with open(path, "rb") as f:
        return [m.log_time for _, _, m in make_reader(f, validate_crcs=True).iter_messages()]


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_cut_anywhere_keeps_the_complete_chunks(tmp_path: Path, compression: str) -> None:
    source = tmp_path / "run.mcap"
    marks = write_chunks(source, compression)
    data = source.read_bytes()
    # at a chunk's end, in its message index, one byte short of a chunk, mid-chunk, in the first chunk
    cuts = [
        marks[2][0],
        marks[2][0] + 5,
        marks[3][0] - 1,
        (marks[3][0] + marks[4][0]) // 2,
        marks[0][0] - 3,
    ]
    for cut in cuts:
        cut_file = tmp_path / f"cut-{cut}.mcap"
        cut_file.write_bytes(data[:cut])
        result = recover(cut_file, tmp_path / f"out-{cut}.mcap", compression=compression)
        expected = max([count for end, count in marks if end <= cut], default=0)
        assert result.messages == expected, f"cut at {cut}"
        assert messages_in(result.target) == list(range(expected))
        assert not result.complete and result.problem
        assert result.readable_bytes <= cut


def test_a_complete_file_is_copied_whole(tmp_path: Path) -> None:
    source = tmp_path / "run.mcap"
    write_chunks(source, "zstd")
    result = recover(source)
    assert result.target == tmp_path / "run-recovered.mcap"
    assert result.complete and result.messages == N_CHUNKS * PER_CHUNK
    assert result.readable_bytes == result.source_bytes
    assert "kept 240 messages" in result.describe()
    assert messages_in(result.target) == list(range(N_CHUNKS * PER_CHUNK))


def test_bad_inputs_name_the_file(tmp_path: Path) -> None:
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    text = tmp_path / "notes.mcap"
    text.write_text("hello, not a recording")
    with pytest.raises(RecordingError, match=r"empty\.mcap: empty file"):
        recover(empty)
    with pytest.raises(RecordingError, match=r"notes\.mcap: not an MCAP file"):
        recover(text)
    with pytest.raises(RecordingError, match=r"missing\.mcap: no such file"):
        recover(tmp_path / "missing.mcap")
    with pytest.raises(RecordingError, match="different output file"):
        recover(text, text)
