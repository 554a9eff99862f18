"""The recorder on the in-memory bus: it records what comes on its keys and the liveliness
of the run, answers the flush barrier, and finishes the file when stopped."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

from formation import keys
from recorder.node import Recorder, build_parser
from recorder.reading.reader import iter_messages, open_recording
from shell import MemoryBus

RUN = "recorder-bus"


def test_a_recording_on_the_memory_bus(tmp_path: Path) -> None:
    bus = MemoryBus()
    recorder = Recorder(build_parser().parse_args(["--run-id", RUN, "--out", str(tmp_path)]))
    alive = keys.alive(RUN, "recorder", 0)
    statuses: list[str] = []
    bus.declare_subscriber(
        keys.status(RUN, "recorder", 0),
        lambda s: statuses.append(json.loads(s.payload.to_bytes())["state"]),
    )
    codes: list[int] = []
    thread = threading.Thread(target=lambda: codes.append(recorder.run(bus)))
    thread.start()
    try:
        deadline = time.monotonic() + 10
        while not list(bus.tokens(alive, 0.0)):  # ready: its subscribers are declared
            assert time.monotonic() < deadline, "the recorder never came up"
            time.sleep(0.01)
        token = bus.declare_token(keys.alive(RUN, "agent", 1))
        bus.put(keys.agent_state(RUN, 1), b'{"x": 1}')
        bus.put(keys.agent_state(RUN, 1), b'{"x": 2}')
        bus.put("elsewhere/agent/1/state", b"not ours")
        token.undeclare()
        (answer,) = bus.get(keys.flush(RUN), timeout_s=5)
        counts = json.loads(answer)
        assert counts[keys.agent_state(RUN, 1)] == 2
    finally:
        recorder.stop.set()
        thread.join(10)
    assert codes == [0] and statuses == ["ready", "done"]
    assert not list(bus.tokens(alive, 0.0))  # gone with the recording
    path = tmp_path / "run.mcap"
    with open_recording(path) as (reader, _):
        got = [(channel.topic, message.data) for _, channel, message in iter_messages(path, reader)]
    states = [data for topic, data in got if topic == keys.agent_state(RUN, 1)]
    assert states == [b'{"x": 1}', b'{"x": 2}']
    alive_events = [json.loads(data)["alive"] for topic, data in got if topic.endswith("agent/1")]
    assert alive_events == [True, False]
    assert not any(topic.startswith("elsewhere") for topic, _ in got)
