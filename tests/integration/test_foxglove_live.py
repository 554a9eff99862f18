"""Watching live (issue 17 item 1): ``formation run --foxglove`` and ``formation replay --foxglove``
seen by an independent client that speaks Foxglove's WebSocket protocol with ``websockets``.

A second client subscribes and never reads; the run must still finish with every epoch
(how fast, against a run without a viewer, is bench/bench_foxglove.py's question).
"""

from __future__ import annotations

import asyncio
import base64
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from foxglove.messages import FrameTransforms, Log, SceneUpdate
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.reader import make_reader

from formation.topics import (
    DECISIONS_TOPIC,
    LOG_TOPIC,
    METRICS_TOPIC,
    SCENE_TOPIC,
    STATS_TOPIC,
    TF_TOPIC,
)
from testbed.runtime.processes import free_port
from testkit import foxglove_client as fc

pytestmark = [pytest.mark.integration, pytest.mark.slow]
EPOCHS = 25
PERIOD_NS = 1_000_000_000  # paper.toml's control.period_s
# Scene last: --foxglove-wait lets the run start once the scene is subscribed.
TOPICS = [DECISIONS_TOPIC, TF_TOPIC, LOG_TOPIC, METRICS_TOPIC, STATS_TOPIC, SCENE_TOPIC]
SCHEMAS = {
    SCENE_TOPIC: ("foxglove.SceneUpdate", "protobuf", "protobuf"),
    TF_TOPIC: ("foxglove.FrameTransforms", "protobuf", "protobuf"),
    LOG_TOPIC: ("foxglove.Log", "protobuf", "protobuf"),
    METRICS_TOPIC: ("formation.EpochMetrics", "json", "jsonschema"),
    DECISIONS_TOPIC: ("formation.DecisionBatch", "json", "jsonschema"),
    STATS_TOPIC: ("formation.LiveStats", "json", "jsonschema"),
}
SDK = {SCENE_TOPIC: SceneUpdate, TF_TOPIC: FrameTransforms, LOG_TOPIC: Log}
RECORDED_KINDS = {
    "scene": SCENE_TOPIC,
    "log": LOG_TOPIC,
    "metrics": METRICS_TOPIC,
    "decision": DECISIONS_TOPIC,
}


def _done(topic: str, payload: bytes) -> bool:
    return topic == STATS_TOPIC and json.loads(payload)["state"] == "done"


async def _watch(url: str, idle: bool) -> fc.Received:
    """Connect once the server accepts, check nothing, subscribe to TOPICS, read to the end."""
    ws = await fc.connect(url, 120.0)
    got = fc.Received()
    await fc.advertised(ws, got, set(TOPICS))
    stalled = await fc.idle_subscriber(url, got.channels) if idle else None
    subs = await fc.subscribe(ws, got, TOPICS)
    await fc.read_until(ws, got, subs, _done, 240.0)
    await ws.close()
    if stalled is not None:
        stalled.transport.abort()
    return got


def _recorded(path: Path) -> dict[str, list[bytes]]:
    """The recorder's scenes, metrics and netem's decisions in the file, by live topic."""
    out: dict[str, list[bytes]] = {t: [] for t in RECORDED_KINDS.values()}
    with open(path, "rb") as f:
        for _, ch, msg in make_reader(f).iter_messages(log_time_order=True):
            topic = RECORDED_KINDS.get(ch.metadata.get("kind", ""))
            if topic is not None:
                out[topic].append(msg.data)
    return out


def _protobuf_class(schema_b64: str, name: str) -> Any:
    """The message class ``name`` of an advertised protobuf schema (a base64 FileDescriptorSet),
    built with the protobuf package alone (not the recorder's decoder)."""
    files = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(schema_b64))
    pool = descriptor_pool.DescriptorPool()
    for proto in files.file:
        pool.Add(proto)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(name))


def _epoch_of_scene(scene_class: Any, payload: bytes) -> int:
    (entity,) = scene_class.FromString(payload).entities
    return int({m.key: m.value for m in entity.metadata}["epoch"])


def _serve(cmd: list[str], log: Path, port: int, idle: bool) -> fc.Received:
    """Start ``formation <cmd>``, watch it to the end, and require a clean exit."""
    with open(log, "w") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "testbed.cli", *cmd, "--foxglove", str(port)],
            stdout=out, stderr=subprocess.STDOUT,
            env={k: v for k, v in os.environ.items() if k != "COLUMNS"},
        )  # fmt: skip
        try:
            got = asyncio.run(_watch(f"ws://127.0.0.1:{port}", idle))
            assert proc.wait(timeout=120) == 0, log.read_text() + _process_logs(cmd)
            assert f"ws://127.0.0.1:{port}" in log.read_text()  # where to point Foxglove
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(10)
    return got


def _process_logs(cmd: list[str]) -> str:
    """The ends of a failed run's process logs (with the stacks a stalled run dumps)."""
    if "--runs-dir" not in cmd:
        return ""
    logs = sorted(Path(cmd[cmd.index("--runs-dir") + 1]).glob("*/logs/*.log"))
    return "".join(f"\n--- {p.name}\n" + "\n".join(p.read_text().splitlines()[-80:]) for p in logs)


def test_live_run_and_replay_reach_an_independent_client(
    paper_path: Path, runs_dir: Path, tmp_path: Path
) -> None:
    cmd = ["run", str(paper_path), "--strategy", "estimate", "--seed", "3", "--epochs", str(EPOCHS),
           "--runs-dir", str(runs_dir), "--foxglove-wait"]  # fmt: skip
    got = _serve(cmd, tmp_path / "run.log", free_port(), idle=True)
    said = (tmp_path / "run.log").read_text()  # off a terminal: a line per run and its progress
    assert "formation run: [1/1] estimate" in said and f"epoch {EPOCHS}/{EPOCHS}" in said
    assert "[pkts]" in said and "[m]" in said  # the summary's units

    assert got.server_info["op"] == "serverInfo" and "time" in got.server_info["capabilities"]
    by_topic = {c["topic"]: c for c in got.channels.values()}
    for topic, (name, encoding, schema_encoding) in SCHEMAS.items():
        ch = by_topic[topic]
        assert (ch["schemaName"], ch["encoding"], ch["schemaEncoding"]) == (
            name,
            encoding,
            schema_encoding,
        )
        assert ch["schema"], topic
        if schema_encoding == "jsonschema":
            assert json.loads(ch["schema"])["type"] == "object", topic
        else:  # the SDK's FileDescriptorSet, base64 on the wire
            assert base64.b64decode(ch["schema"]) == bytes(SDK[topic].get_schema().data), topic
    scene_class = _protobuf_class(by_topic[SCENE_TOPIC]["schema"], "foxglove.SceneUpdate")
    tf_class = _protobuf_class(by_topic[TF_TOPIC]["schema"], "foxglove.FrameTransforms")
    log_class = _protobuf_class(by_topic[LOG_TOPIC]["schema"], "foxglove.Log")

    (mcap_path,) = runs_dir.glob("*/run.mcap")
    recorded = _recorded(mcap_path)
    every = list(range(EPOCHS + 1))  # the final states are epoch EPOCHS
    scenes, metrics = got.on(SCENE_TOPIC), got.on(METRICS_TOPIC)
    assert [_epoch_of_scene(scene_class, s) for s in scenes] == every
    assert [json.loads(m)["epoch"] for m in metrics] == every
    assert scenes == recorded[SCENE_TOPIC]  # one drawing: the bytes the file holds
    assert metrics == recorded[METRICS_TOPIC]
    assert got.log_times(SCENE_TOPIC) == [k * PERIOD_NS for k in every]  # sim time
    assert got.times == [k * PERIOD_NS for k in every]  # the timeline follows the run
    tf = [tf_class.FromString(t).transforms for t in got.on(TF_TOPIC)]
    assert len(tf) == len(every)
    assert all([t.child_frame_id for t in frames] == [f"agent{i}" for i in range(1, 6)]
               and {t.parent_frame_id for t in frames} == {"world"} for frames in tf)  # fmt: skip
    logs = [log_class.FromString(line) for line in got.on(LOG_TOPIC)]
    assert logs and got.on(LOG_TOPIC) == recorded[LOG_TOPIC]  # the processes' ends, as recorded
    assert {line.name for line in logs} >= {"netem", "leader", "agent/1"}
    assert got.on(DECISIONS_TOPIC) == recorded[DECISIONS_TOPIC]
    stats = json.loads(got.on(STATS_TOPIC)[-1])
    assert stats["state"] == "done" and stats["epoch"] == EPOCHS
    assert (
        json.loads(_stats(mcap_path)["live"]) == stats
    )  # the file says what the viewer was offered, sent and dropped

    replay = ["replay", str(mcap_path), "--rate", "200"]
    again = _serve(replay, tmp_path / "replay.log", free_port(), idle=False)
    for topic, messages in recorded.items():  # as many as the file holds, the same bytes
        assert again.on(topic) == messages, topic
    assert len(again.on(TF_TOPIC)) == len(recorded[METRICS_TOPIC])


def _stats(path: Path) -> dict[str, str]:
    with open(path, "rb") as f:
        for record in make_reader(f).iter_metadata():
            if record.name == "recorder_stats":
                return dict(record.metadata)
    raise AssertionError(f"{path}: no recorder_stats")
