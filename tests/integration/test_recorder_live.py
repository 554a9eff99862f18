"""The recorder as a real process over Zenoh on 127.0.0.1: counts, schemas, kill -9.

The test process is a Zenoh peer listening on a free port; the recorder connects to it in
client mode, as the launcher starts it (``testkit/src/testkit/zenoh_peer.py``). Readiness is a
liveliness token or a queryable's reply, never a fixed sleep; every process is ended by PID
in a ``finally``. Replaying a recording: ``test_recorder_replay.py``.
"""

from __future__ import annotations

import json
import os
import signal
from collections import Counter
from pathlib import Path
from typing import Any

import pytest
import zenoh
from mcap.reader import make_reader
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader

from formation import keys
from formation.codec import attachment, encode
from formation.errors import RecordingError
from formation.messages import Decision, DecisionBatch, Status
from formation.scenario import Scenario
from recorder.reading.reader import describe, validate
from recorder.reading.recovery import recover
from testkit.zenoh_peer import WAIT_S, peer, process, state, token_seen, wait_for

pytestmark = pytest.mark.integration


def start_recorder(run_id: str, out: Path, endpoint: str, *extra: str) -> list[str]:
    return [
        "-m",
        "recorder",
        "--run-id",
        run_id,
        "--out",
        str(out),
        "--mode",
        "client",
        "--connect",
        endpoint,
        "--no-live",
        *extra,
    ]


def recorded_counts(session: Any, run_id: str) -> dict[str, int]:
    """The recorder's flush barrier: its counts per key of everything it has received."""
    for reply in session.get(keys.flush(run_id), timeout=5.0):
        if reply.ok is not None:
            return dict(json.loads(reply.ok.payload.to_bytes()))
    return {}


def test_recorder_keeps_every_message_with_its_schema(
    tmp_path: Path, paper: Scenario, paper_path: Path
) -> None:
    """Messages on 14 keys from another process: counts equal, all validate, scenario stored."""
    run_id, out, log = "rec-count", tmp_path / "out", tmp_path / "recorder.log"
    sent: Counter[str] = Counter()
    epochs, bulk = 4, 3000
    with (
        peer() as (session, endpoint),
        process(
            *start_recorder(run_id, out, endpoint, "--scenario", str(paper_path)), log=log
        ) as proc,
    ):
        with token_seen(session, keys.alive(run_id, "recorder", 0)) as ready:
            wait_for(ready, proc, "the recorder's token", log)
        pubs: dict[str, Any] = {}

        def put(key: str, payload: bytes, att: bytes | None = None) -> None:
            if key not in pubs:
                pubs[key] = session.declare_publisher(
                    key, congestion_control=zenoh.CongestionControl.BLOCK
                )
            pubs[key].put(payload, attachment=att)
            sent[key] += 1

        for k in range(epochs):
            for i in range(1, paper.n + 1):
                put(
                    keys.agent_state(run_id, i),
                    state(run_id, i, k, (paper.offsets[i - 1] + 0.01 * k).tolist()),
                    attachment(k, k, i),
                )
            decisions = [
                Decision(source=1, target=2, link_class="formation", epoch=k, seq=k, verdict="drop")
            ]
            put(
                keys.netem_decision(run_id),
                encode(
                    DecisionBatch.of_rows(
                        run_id=run_id,
                        sender="netem",
                        seq=k,
                        epoch=k,
                        stamp_ns=1,
                        phase="state",
                        decisions=decisions,
                    )
                ),
            )
            put(
                keys.status(run_id, "agent", 1),
                encode(
                    Status(
                        run_id=run_id,
                        sender="agent/1",
                        seq=k,
                        epoch=k,
                        stamp_ns=1,
                        role="agent",
                        state="running",
                    )
                ),
            )
        for n in range(bulk):  # a burst on the delivered-state keys
            i, j = (1, 3) if n % 2 else (3, 1)
            put(
                keys.link_state(run_id, i, j), state(run_id, i, n, [0.5, 0.25]), attachment(n, n, i)
            )
        put(f"{keys.prefix(run_id)}/custom/thing", b'{"free": "form"}')
        wait_for(
            lambda: all(recorded_counts(session, run_id).get(k, 0) >= v for k, v in sent.items()),
            proc,
            "the flush barrier",
            log,
        )
        os.kill(proc.pid, signal.SIGTERM)
        assert proc.wait(timeout=WAIT_S) == 0, log.read_text()

    info = describe(out / "run.mcap")
    counts = {c.topic: c.messages for c in info.channels}
    assert {k: counts.get(k) for k in sent} == dict(sent)
    assert counts[keys.metrics(run_id)] == epochs  # every epoch complete → metrics and a scene
    assert counts[keys.scene(run_id)] == epochs
    assert counts[keys.alive(run_id, "recorder", 0)] >= 1
    assert info.drops == {"formation 1->2": epochs}
    assert info.scenario is not None and info.scenario.to_toml() == paper.to_toml()
    assert info.metadata["recorder_stats"]["dropped"] == "0"
    check = validate(out / "run.mcap")
    assert check.failures == 0, check.examples
    assert check.by_schema["foxglove.SceneUpdate"] == epochs
    assert check.by_schema["unknown"] == 1
    assert (out / "scenario.toml").read_text() == paper.to_toml()


def readable(path: Path) -> list[tuple[Channel, Message]]:
    """The messages of complete chunks of a file that may be cut anywhere."""
    channels: dict[int, Channel] = {}
    got = []
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f).records:
                if isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Message):
                    got.append((channels[record.channel_id], record))
        except Exception:  # any torn record ends the readable prefix (EndOfFile, zstd, CRC, ...)
            pass
    return got


def test_kill_9_loses_at_most_the_open_chunk(tmp_path: Path) -> None:
    """N1 = 2000 messages are on disk before the kill (the test waits for them); N2 = 3000 more
    are sent just before SIGKILL. ``recover`` keeps exactly seq 0 .. c − 1 with c ≥ N1: every
    complete chunk, no gap; only the chunk open at the kill is lost."""
    run_id, out, log = "rec-kill", tmp_path / "out", tmp_path / "recorder.log"
    key, n1, n2 = keys.link_state(run_id, 2, 4), 2000, 3000
    with (
        peer() as (session, endpoint),
        process(
            *start_recorder(
                run_id, out, endpoint, "--chunk-interval", "0.05", "--chunk-size", "16K"
            ),
            log=log,
        ) as proc,
    ):
        with token_seen(session, keys.alive(run_id, "recorder", 0)) as ready:
            wait_for(ready, proc, "the recorder's token", log)
        pub = session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
        payloads = [state(run_id, 2, n, [1.0, 2.0]) for n in range(n1 + n2)]
        for n in range(n1):
            pub.put(payloads[n], attachment=attachment(n, n, 2))
        on_disk = lambda: sum(1 for ch, _ in readable(out / "run.mcap") if ch.topic == key) >= n1  # noqa: E731
        wait_for(on_disk, proc, f"{n1} messages on disk", log)
        for n in range(n1, n1 + n2):
            pub.put(payloads[n], attachment=attachment(n, n, 2))
        os.kill(proc.pid, signal.SIGKILL)
        assert proc.wait(timeout=WAIT_S) == -signal.SIGKILL

    with pytest.raises(RecordingError, match=r"run\.mcap: truncated MCAP file"):
        describe(out / "run.mcap")
    result = recover(out / "run.mcap")
    with open(result.target, "rb") as f:
        seqs = [
            m.sequence
            for _, ch, m in make_reader(f, validate_crcs=True).iter_messages()
            if ch.topic == key
        ]
    assert len(seqs) >= n1, result.describe()
    assert seqs == list(range(len(seqs)))  # a prefix of what was sent, no gap
    assert len(seqs) <= n1 + n2
    assert [m.data for ch, m in readable(result.target) if ch.topic == key] == payloads[: len(seqs)]
