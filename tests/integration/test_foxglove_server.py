"""The live view's server alone (recorder/live/server.py) with the independent client, on loopback.

What a run cannot show deterministically: a full queue drops the oldest and counts it; a
forged decision never reaches the viewer; a taken port is a clear error.
"""

from __future__ import annotations

import asyncio
import json
import socket
import time
from collections.abc import Callable

import pytest

from formation import keys
from formation.codec import encode
from formation.errors import TestbedError
from formation.messages import Decision, DecisionBatch, EpochMetrics
from formation.scenario import Scenario
from formation.topics import DECISIONS_TOPIC, METRICS_TOPIC, STATS_TOPIC, TF_TOPIC
from recorder.live.server import STOP_S, LiveServer
from recorder.reading.trust import Gate
from testkit import foxglove_client as fc

pytestmark = pytest.mark.integration
RUN = "live-test"
TOPICS = [DECISIONS_TOPIC, TF_TOPIC, METRICS_TOPIC, STATS_TOPIC]


def _metrics(paper: Scenario, epoch: int) -> bytes:
    return encode(
        EpochMetrics(
            run_id=RUN, sender="recorder", seq=epoch, epoch=epoch, stamp_ns=1,
            formation_error_m=0.1 * epoch, shape_error_m=0.0,
            positions=[[float(i), 2.0 * epoch] for i in range(paper.n)],
        )
    )  # fmt: skip


def _decisions(sender: str, epoch: int) -> bytes:
    dec = Decision(source=1, target=2, link_class="formation", epoch=epoch, seq=0, verdict="drop")
    return encode(
        DecisionBatch.of_rows(run_id=RUN, sender=sender, seq=epoch, epoch=epoch, stamp_ns=1,
                      phase="state", decisions=[dec])
    )  # fmt: skip


def _watch(live: LiveServer, feed: Callable[[], None]) -> fc.Received:
    """Subscribe to TOPICS, then ``feed`` and close the server (in a thread); read to the end."""

    async def run() -> fc.Received:
        ws = await fc.connect(live.url, 10.0)
        got = fc.Received()
        await fc.advertised(ws, got, set(TOPICS))
        subs = await fc.subscribe(ws, got, TOPICS)
        assert await asyncio.to_thread(live.wait_for_topics, set(TOPICS), 10.0)
        closing = asyncio.create_task(asyncio.to_thread(lambda: (feed(), live.close())))
        await fc.read_until(ws, got, subs, _done, 30.0)
        await ws.close()
        await closing
        return got

    return asyncio.run(run())


def _done(topic: str, payload: bytes) -> bool:
    return topic == STATS_TOPIC and json.loads(payload)["state"] == "done"


def test_a_full_queue_drops_the_oldest_and_counts_them(paper: Scenario) -> None:
    live = LiveServer(paper, 0, queue_limit=3)  # not started: what is offered waits
    for k in range(5):
        live.offer("metrics", keys.metrics(RUN), _metrics(paper, k))
    assert (live.offered, live.dropped) == (5, 2)

    got = _watch(live, live.start)

    assert [json.loads(m)["epoch"] for m in got.on(METRICS_TOPIC)] == [2, 3, 4]  # the newest
    assert len(got.on(TF_TOPIC)) == 3
    period_ns = round(paper.control.period_s * 1e9)
    assert got.log_times(METRICS_TOPIC) == [k * period_ns for k in (2, 3, 4)]
    final = json.loads(got.on(STATS_TOPIC)[-1])
    assert final == {"state": "done", "epoch": 4, "offered": 5, "sent": 6, "dropped": 2,
                     "skipped": 0}  # fmt: skip


def test_a_forged_decision_never_reaches_the_viewer(paper: Scenario) -> None:
    live = LiveServer(paper, 0, gate=Gate(paper, conflicts=False)).start()

    def feed() -> None:
        live.offer("decision", keys.netem_decision(RUN), _decisions("agent/1", 3))  # not netem
        live.offer("decision", keys.netem_decision(RUN), b"\x00 not json")
        live.offer("decision", keys.netem_decision(RUN), _decisions("netem", 4))

    got = _watch(live, feed)

    assert got.on(DECISIONS_TOPIC) == [_decisions("netem", 4)]
    assert json.loads(got.on(STATS_TOPIC)[-1])["skipped"] == 2


def test_a_scene_or_log_line_that_is_not_protobuf_is_skipped(paper: Scenario) -> None:
    live = LiveServer(paper, 0).start()

    def feed() -> None:
        live.offer("scene", keys.scene(RUN), b'{"entities": []}')  # a JSON scene of old
        live.offer("log", keys.log(RUN), b"\xff\xff")
        live.offer("decision", keys.netem_decision(RUN), _decisions("netem", 4))

    got = _watch(live, feed)

    assert got.on(DECISIONS_TOPIC) == [_decisions("netem", 4)]  # the server went on
    assert json.loads(got.on(STATS_TOPIC)[-1])["skipped"] == 2


def test_a_taken_port_is_a_clear_error(paper: Scenario) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(TestbedError, match=rf"--foxglove {port}: cannot serve on 127.0.0.1:"):
            LiveServer(paper, port)


def test_a_viewer_that_never_reads_does_not_hold_the_server_at_its_end(paper: Scenario) -> None:
    # The SDK's stop waits for each client's close; a client that reads nothing never takes it.
    live = LiveServer(paper, 0).start()

    async def stall() -> float:
        ws = await fc.connect(live.url, 10.0)
        got = fc.Received()
        await fc.advertised(ws, got, {METRICS_TOPIC})
        idle = await fc.idle_subscriber(live.url, got.channels)
        await ws.close()
        assert await asyncio.to_thread(live.wait_for_topics, {METRICS_TOPIC}, 10.0)

        def feed_and_close() -> float:
            for epoch in range(20_000):  # far more than its socket buffers and the backlog hold
                live.offer("metrics", keys.metrics(RUN), _metrics(paper, epoch))
            started = time.monotonic()
            live.close(linger_s=0.0)
            return time.monotonic() - started

        took = await asyncio.to_thread(feed_and_close)
        idle.transport.abort()
        return took

    took = asyncio.run(stall())  # bounded by pytest's timeout: it never ended before
    assert took < 10 * STOP_S, f"close took {took:.1f} s"
    assert live.offered == 20_000
