"""Replay timing and control without the network: a publish function collects what goes out."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest

from formation import keys
from formation.codec import attachment, encode, read_attachment
from formation.errors import TestbedError
from formation.messages import CoordinationState
from recorder.playback.player import Replayer, rebuild_attachment
from recorder.recording.writer import RecordingWriter

RUN = "rp"
GAP_NS = 100_000_000  # 0.1 s between recorded messages


def state(i: int, k: int) -> bytes:
    msg = CoordinationState(
        run_id=RUN, sender=f"agent/{i}", seq=k, epoch=k, stamp_ns=0, agent=i, position=[k, 0.0]
    )
    return encode(msg)


@pytest.fixture
def recording(tmp_path: Path) -> Path:
    path = tmp_path / "run.mcap"
    rec = RecordingWriter(path)
    for k in range(10):
        rec.write(keys.agent_state(RUN, 1 + k % 2), state(1 + k % 2, k), 10**12 + k * GAP_NS)
    rec.write(keys.alive(RUN, "agent", 1), b'{"alive": true}', 10**12)
    rec.close()
    return path


class Sink:
    def __init__(self) -> None:
        self.got: list[tuple[float, str, bytes, bytes | None]] = []

    def __call__(self, key: str, data: bytes, att: bytes | None) -> None:
        self.got.append((time.monotonic(), key, data, att))


def test_replays_in_order_with_scaled_timing_and_a_new_prefix(recording: Path) -> None:
    sink = Sink()
    rp = Replayer(recording, rate=4.0, prefix="formation/again")
    state_ = rp.run(sink, threading.Event())
    assert state_.done and state_.published == 10
    assert [k for _, k, _, _ in sink.got] == [
        f"formation/again/agent/{1 + k % 2}/state" for k in range(10)
    ]
    assert [read_attachment(a) for _, _, _, a in sink.got] == [(k, k, 1 + k % 2) for k in range(10)]
    elapsed = sink.got[-1][0] - sink.got[0][0]
    nominal = 9 * 0.1 / 4  # nine gaps of 0.1 s at rate 4
    assert 0.95 * nominal <= elapsed < nominal + 0.5  # clock reads and scheduling slack


def test_start_offset_and_topic_filter(recording: Path) -> None:
    sink = Sink()
    Replayer(recording, rate=50.0, start_s=0.5, topics=[f"formation/{RUN}/agent/2/state"]).run(
        sink, threading.Event()
    )
    assert [k for _, k, _, _ in sink.got] == [
        keys.agent_state(RUN, 2)
    ] * 3  # agent 2 sends odd epochs
    assert [read_attachment(a)[0] for *_, a in sink.got] == [5, 7, 9]  # type: ignore[index]


def test_pause_resume_rate_and_seek(recording: Path) -> None:
    sink = Sink()
    rp = Replayer(recording, rate=1.0, paused=True)
    stop = threading.Event()
    worker = threading.Thread(target=rp.run, args=(sink, stop))
    worker.start()
    try:
        time.sleep(0.3)
        assert sink.got == []  # paused from the start
        rp.command("rate", 10.0)
        rp.command("resume")
        deadline = time.monotonic() + 5
        while len(sink.got) < 3 and time.monotonic() < deadline:
            time.sleep(0.005)
        rp.command("pause")
        count = len(sink.got)
        time.sleep(0.2)
        assert len(sink.got) <= count + 1  # at most one already due when paused
        assert rp.command("status").paused
        rp.command("seek", 0.0)
        rp.command("resume")
        worker.join(10)
        assert not worker.is_alive()
    finally:
        stop.set()
        worker.join(5)
    epochs = [read_attachment(a)[0] for *_, a in sink.got]  # type: ignore[index]
    restart = epochs.index(0, 1)
    assert epochs[restart:] == list(range(10))  # the seek replayed everything again
    assert rp.state.published == len(sink.got)


def test_loop_starts_again_until_stopped(recording: Path) -> None:
    sink = Sink()
    rp = Replayer(recording, rate=100.0, loop=True)
    stop = threading.Event()
    worker = threading.Thread(target=rp.run, args=(sink, stop))
    worker.start()
    try:
        deadline = time.monotonic() + 10
        while rp.command("status").loops < 2 and time.monotonic() < deadline:
            time.sleep(0.005)
    finally:
        stop.set()
        worker.join(5)
    assert not worker.is_alive()
    epochs = [read_attachment(a)[0] for *_, a in sink.got]  # type: ignore[index]
    assert epochs[:20] == list(range(10)) * 2
    assert not rp.state.done


def test_rebuilt_attachments() -> None:
    assert rebuild_attachment("control", b'{"epoch": 1, "seq": 2}') is None
    assert rebuild_attachment("leader_estimate", b'{"epoch": 1, "seq": 2}') == attachment(
        1, 2, keys.LEADER_ENDPOINT
    )
    assert rebuild_attachment("link_state", b'{"epoch": 3, "seq": 4, "agent": 5}') == attachment(
        3, 4, 5
    )
    assert rebuild_attachment("agent_state", b"not json") is None


def test_invalid_controls(recording: Path) -> None:
    rp = Replayer(recording)
    with pytest.raises(TestbedError, match="unknown command 'jump'"):
        rp.command("jump")
    with pytest.raises(TestbedError, match="rate needs a value > 0, got -1"):
        rp.command("rate", -1)
    with pytest.raises(TestbedError, match="seek needs a value in seconds >= 0, got None"):
        rp.command("seek")
    with pytest.raises(TestbedError, match=r"--rate 0; expected > 0"):
        Replayer(recording, rate=0)
