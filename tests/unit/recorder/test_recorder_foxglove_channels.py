"""The recording's Foxglove channels: the SDK's protobuf schemas, scenes that decode to the
team, payloads that do not decode counted and skipped by every reader (never a crash), and
the channels kept by recovery."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from foxglove.messages import FrameTransforms, SceneUpdate
from mcap.reader import make_reader

from formation import keys
from recorder import load_run
from recorder.live.scene import AGENT_COLOR, LEADER_COLOR, TREE
from recorder.playback.player import Replayer
from recorder.reading.decoder import as_dict, decode, decode_kind
from recorder.reading.reader import validate
from recorder.reading.recovery import recover
from recorder.reading.trust import INVALID, Gate
from recorder.recording.schemas import foxglove_schema

EPOCH_NS = 1_000_000_000


@pytest.fixture
def recording(tmp_path: Path, sim_results: dict[str, Any], synth: Any) -> tuple[Path, Any]:
    result = sim_results["estimate"]
    path = tmp_path / "run.mcap"
    synth.write(path, result)
    return path, result


def _channels(path: Path) -> dict[str, tuple[Any, Any, list[bytes]]]:
    """Per channel kind: (channel, schema, payloads in log-time order)."""
    out: dict[str, tuple[Any, Any, list[bytes]]] = {}
    with open(path, "rb") as f:
        for schema, ch, msg in make_reader(f).iter_messages(log_time_order=True):
            out.setdefault(ch.metadata["kind"], (ch, schema, []))[2].append(msg.data)
    return out


def test_scene_and_frames_are_the_sdk_s_protobuf_messages(recording: tuple[Path, Any]) -> None:
    path, _ = recording
    got = _channels(path)
    for kind, sdk in (("scene", SceneUpdate), ("tf", FrameTransforms)):
        ch, schema, _ = got[kind]
        theirs = sdk.get_schema()
        assert (ch.message_encoding, schema.encoding) == ("protobuf", "protobuf")
        assert (schema.name, schema.data) == (theirs.name, bytes(theirs.data))
        assert ch.metadata["origin"] == "recorder"
    assert got["metrics"][0].message_encoding == "json"
    assert validate(path).failures == 0  # every message against its recorded schema


def test_a_recorded_scene_decodes_to_the_team(recording: tuple[Path, Any]) -> None:
    path, result = recording
    s = result.scenario
    _, schema, scenes = _channels(path)["scene"]
    assert len(scenes) == len(result.positions)  # every epoch, the final states too
    for k, raw in enumerate(scenes):
        (team,) = as_dict(decode(schema.name, schema.data, raw))["entities"]  # the file's schema
        assert team["metadata"] == [{"key": "epoch", "value": str(k)}]
        agents = [sp for sp in team["spheres"]
                  if (sp["color"]["r"], sp["color"]["b"]) in {(c[0], c[2]) for c in (AGENT_COLOR, LEADER_COLOR)}]  # fmt: skip
        centres = [[sp["pose"]["position"]["x"], sp["pose"]["position"]["y"]] for sp in agents]
        np.testing.assert_array_equal(centres, result.positions[k])
        edges = [ln for ln in team["lines"] if ln["thickness"] in (2.0, 4.0)]
        assert sum(len(ln["points"]) // 2 for ln in edges) == len(s.edges)  # each edge once
        if k < s.epochs:
            tree = [ln for ln in edges if ln["color"]["g"] == TREE[1] and ln["thickness"] == 4.0]
            assert sum(len(ln["points"]) // 2 for ln in tree) == int(result.tree[k].sum())
    _, _, frames = _channels(path)["tf"]
    assert len(frames) == len(scenes)
    last = decode_kind("tf", frames[-1]).transforms  # type: ignore[attr-defined]
    assert [t.child_frame_id for t in last] == [f"agent{i}" for i in range(1, s.n + 1)]
    assert [[t.translation.x, t.translation.y] for t in last] == result.positions[-1].tolist()


def test_payloads_that_are_not_protobuf_are_counted_and_skipped(
    tmp_path: Path, sim_results: dict[str, Any], synth: Any
) -> None:
    result = sim_results["hold"]
    bad = [
        (keys.scene(synth.RUN), b'{"deletions": [], "entities": []}', 3 * EPOCH_NS + 7),  # JSON
        (keys.scene(synth.RUN), b"\xff\xff\xff", 4 * EPOCH_NS + 7),
        (keys.scene(synth.RUN), b"\x12\x00", 5 * EPOCH_NS),  # decodes: an entity without an id
        (keys.frames(synth.RUN), b"not frames", 5 * EPOCH_NS + 7),
        (keys.log(synth.RUN), b"\x0a\xff", 6 * EPOCH_NS + 7),
    ]
    path = tmp_path / "run.mcap"
    synth.write(path, result, derived=bad)
    run = load_run(path)
    by_topic = {key: 0 for key, _, _ in bad}
    for key, _, _ in bad:
        by_topic[key] += 1
    assert run.skipped.by_channel() == by_topic
    assert run.skipped.by_reason() == {INVALID: len(bad)}
    np.testing.assert_array_equal(
        run.states.pivot(index="epoch", columns="agent", values="x").to_numpy(),
        result.positions[:, :, 0],
    )  # the numbers are the clean run's
    replayer = Replayer(path, rate=1e9)
    published: list[str] = []
    state = replayer.run(lambda key, data, att: published.append(key), threading.Event())
    assert state.skipped == len(bad)
    assert published.count(keys.scene(synth.RUN)) == len(result.positions)
    assert validate(path).failures == len(bad) - 1  # an entity without an id is valid protobuf


def test_a_recovered_recording_keeps_its_protobuf_channels(
    recording: tuple[Path, Any], tmp_path: Path
) -> None:
    path, _ = recording
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size * 2 // 3])  # a killed recorder
    result = recover(cut, tmp_path / "recovered.mcap")
    assert result.messages > 0 and not result.complete
    got = _channels(result.target)
    for kind in ("scene", "tf"):
        ch, schema, payloads = got[kind]
        assert (ch.message_encoding, schema.encoding) == ("protobuf", "protobuf")
        assert schema.data == foxglove_schema(kind).data
        assert payloads and all(decode(schema.name, schema.data, p) for p in payloads)
    assert load_run(result.target).skipped.total == 0


def test_a_scene_the_recorder_marked_as_its_own_is_outlined_when_read_in_bulk(
    paper: Any,
) -> None:
    # an entity with an id and a sphere (field 9) whose bytes do not parse as one
    entity = b"\x1a\x01a" + b"\x4a\x02\xff\xff"
    scene = b"\x12" + bytes([len(entity)]) + entity
    topic = keys.scene("r")
    own = Gate(paper, plain_bulk=True)
    own.derived_channels = {7}
    assert own.check(topic, scene, "scene", 7) is not None  # framed, with ids: not parsed further
    for bad in (b"\xff\xff\xff", b"\x12\x00", b'{"entities": []}'):  # no frame, no id, JSON
        assert own.check(topic, bad, "scene", 7) is None
    assert own.skipped.by_reason() == {INVALID: 3}
    assert own.check(topic, scene, "scene", 8) is None  # not the recorder's channel: forged
    unmarked = Gate(paper, plain_bulk=True)  # an older recording marks no channel
    for gate in (Gate(paper), unmarked):  # parsed whole: the sphere is refused
        assert gate.check(topic, scene, "scene", 7) is None
        assert gate.skipped.by_reason() == {INVALID: 1}
