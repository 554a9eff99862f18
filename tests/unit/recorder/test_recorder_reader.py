"""Reading recordings: clear errors for bad files, info, validation against stored schemas."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

from formation import keys
from formation.errors import RecordingError
from recorder.reading.reader import check_file, describe, validate
from recorder.recording.writer import RecordingWriter

RUN = "synthetic"  # the run id of conftest's synthetic recordings


def bad_files(tmp_path: Path, good: Path) -> dict[str, Path]:
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    text = tmp_path / "text.mcap"
    text.write_text("not an mcap file at all")
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    return {"empty": empty, "text": text, "cut": cut}


@pytest.fixture
def good(tmp_path: Path, sim_results: dict[str, Any], synth: Any) -> Path:
    path = tmp_path / "run.mcap"
    synth.write(path, sim_results["hold"])
    return path


def test_bad_files_are_named_in_the_error(tmp_path: Path, good: Path) -> None:
    files = bad_files(tmp_path, good)
    with pytest.raises(RecordingError, match=r"empty\.mcap: empty file \(0 bytes\)"):
        check_file(files["empty"])
    with pytest.raises(
        RecordingError, match=r"text\.mcap: not an MCAP file \(starts with b'not an m'\)"
    ):
        check_file(files["text"])
    with pytest.raises(
        RecordingError,
        match=r"cut\.mcap: truncated MCAP file \(\d+ bytes, no footer\).*`formation recover ",
    ):
        check_file(files["cut"])
    with pytest.raises(RecordingError, match=r"nothing\.mcap: no such file"):
        describe(tmp_path / "nothing.mcap")
    with pytest.raises(RecordingError, match=re.escape(f"{tmp_path}: not a file")):
        check_file(tmp_path)


def test_info_counts_channels_and_drops(good: Path, sim_results: dict[str, Any]) -> None:
    info = describe(good)
    result = sim_results["hold"]
    counts = {c.topic: c.messages for c in info.channels}
    epochs = len(result.positions)
    assert counts[keys.agent_state(RUN, 3)] == epochs
    assert counts[keys.leader_estimate_out(RUN)] == epochs - 1
    assert counts[keys.metrics(RUN)] == epochs
    assert counts[keys.scene(RUN)] == epochs
    assert info.messages == sum(counts.values())
    assert info.scenario is not None and info.scenario.name == "paper"
    drops = {link: int((~result.delivered[:, c]).sum()) for c, link in enumerate(
        f"formation {a}->{b}" for a, b in result.scenario.directed_links)}  # fmt: skip
    assert dict(info.drops) == {k: v for k, v in drops.items() if v}
    assert info.drops["formation 1->2"] == epochs - 2  # down from epoch 1
    assert info.sent["formation 3->5"] == epochs - 1
    assert info.duration_s > 0 and info.compression == "zstd"


def test_every_message_validates_against_its_stored_schema(good: Path) -> None:
    check = validate(good)
    assert check.failures == 0, check.examples
    assert check.checked > 300
    assert check.by_schema["foxglove.SceneUpdate"] > 0
    assert check.by_schema["formation.LeaderEstimate"] > 0


def test_validation_reports_a_bad_message(tmp_path: Path) -> None:
    path = tmp_path / "bad.mcap"
    rec = RecordingWriter(path)
    rec.write(keys.agent_state(RUN, 1), b'{"kind": "state", "agent": "one"}', 1)
    rec.write(keys.metrics(RUN), b"not json", 2)
    rec.write("free/form", b'{"anything": [1, 2]}', 3)
    rec.close()
    check = validate(path)
    assert check.checked == 3 and check.failures == 2
    assert check.examples[0][0] == keys.agent_state(RUN, 1)
    assert "formation.CoordinationState" in check.examples[0][2]
    assert check.examples[1][2].startswith("not JSON")
