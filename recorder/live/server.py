"""The live view: a run, or a recording, served to Foxglove over its WebSocket protocol.

:class:`LiveServer` runs Foxglove's SDK server on ``127.0.0.1:<port>`` (subprotocol
``foxglove.sdk.v1``, the ``foxglove.websocket.v1`` protocol under its new name) with
these channels, whatever the run id, so one layout (``foxglove-layout/formation-layout.json``)
fits every run:

- ``/formation/scene``: the recorder's ``foxglove.SceneUpdate`` (protobuf) of each epoch,
  the bytes it records (:mod:`recorder.live.scene`, one drawing for the file and the viewer);
- ``/tf``: ``foxglove.FrameTransforms``, frame ``agent<i>`` at agent ``i``'s true position
  in ``world``, from the epoch's metrics (:func:`recorder.live.scene.frame_transforms`, as the
  recording's, stamped with the sim time);
- ``/formation/log``: the recorder's ``foxglove.Log`` lines (:mod:`recorder.live.logs`), the
  bytes it records;
- ``/formation/metrics``: ``EpochMetrics`` (formation and shape error per epoch, plottable);
- ``/netem/decisions``: netem's ``DecisionBatch``es (only those the trust gate passes);
- ``/formation/live``: what the live view offered, sent and dropped, every second and at
  the end.

Every message's log time is the run's sim time, epoch × ``control.period_s``, and the
server broadcasts the newest sim time, so Foxglove's timeline follows the run.

A slow or absent viewer never slows the run: :meth:`LiveServer.offer` puts the message on
a bounded queue and returns; when the queue is full the oldest message goes and is
counted (:attr:`LiveServer.dropped`). Only the server's thread parses and sends, and the
SDK drops the oldest messages of a client that does not read (``message_backlog_size``).
The recording never sees any of this. A replay offers with ``block=True`` instead:
nothing is dropped, the replay waits.

The SDK discards what it has not yet sent when it stops, so :meth:`close` keeps the
server up after the last message until every viewer has left or :data:`LINGER_S` passed.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from typing import Any

import foxglove
import orjson
from foxglove.channels import FrameTransformsChannel
from foxglove.websocket import Capability, ChannelView, Client, ServerListener

from formation.errors import TestbedError
from formation.messages import DecisionBatch, EpochMetrics
from formation.scenario import Scenario
from formation.topics import (
    DECISIONS_TOPIC,
    LOG_TOPIC,
    METRICS_TOPIC,
    SCENE_TOPIC,
    STATS_TOPIC,
    TF_TOPIC,
)
from recorder.live.scene import frame_transforms
from recorder.reading.decoder import DecodeError, decode_kind
from recorder.reading.trust import Gate
from recorder.recording.schemas import SchemaSpec, foxglove_schema, message_encoding, model_schema

log = logging.getLogger("recorder")
HOST = "127.0.0.1"  # the live view listens on loopback only
QUEUE_LIMIT = 4096  # messages waiting for the server's thread before the oldest is dropped
BACKLOG = 4096  # per viewer, in the SDK (it drops a slow viewer's oldest)
LINGER_S = 2.0  # longest wait at the end for viewers to take the last messages [s]
# The SDK's stop waits for each client's connection to close, and one that never reads never
# takes the close: seen holding the recorder until the launcher killed it (bench_stress, grid20).
STOP_S = 3.0
STATS_PERIOD_S = 1.0  # how often /formation/live goes out [s]
LIVE_KINDS = ("scene", "log", "metrics", "decision")  # channel kinds a live view takes

STATS_SCHEMA = {
    "type": "object",
    "title": "formation.LiveStats",
    "properties": {
        "state": {"type": "string", "enum": ["running", "done"]},
        "epoch": {"type": "integer", "description": "newest epoch sent"},
        "offered": {"type": "integer", "description": "messages handed to the live view"},
        "sent": {"type": "integer", "description": "messages put on the server's channels"},
        "dropped": {"type": "integer", "description": "oldest messages dropped: queue full"},
        "skipped": {"type": "integer", "description": "decisions the trust gate refused"},
    },
}


def _channel(topic: str, kind: str, ctx: foxglove.Context) -> foxglove.Channel:
    """A channel of the recorder's messages of ``kind``, with the schema and encoding it records."""
    spec = foxglove_schema(kind)
    return foxglove.Channel(
        topic, schema=_schema(spec), message_encoding=message_encoding(kind), context=ctx
    )


def _schema(spec: SchemaSpec) -> foxglove.Schema:
    return foxglove.Schema(name=spec.name, encoding=spec.encoding, data=spec.data)


def scene_epoch(payload: bytes) -> int:
    """The epoch a recorder scene is of (its entity's ``epoch`` metadata); -1 if none.

    Raises :class:`~recorder.reading.decoder.DecodeError` if ``payload`` is not a protobuf scene.
    """
    for ent in decode_kind("scene", payload).entities:
        for item in ent.metadata:
            if item.key == "epoch":
                return int(item.value)
    return -1


class _Subscriptions(ServerListener):
    """The SDK's server listener: which viewer is subscribed to which channel."""

    def __init__(self) -> None:
        self.lock = threading.Condition()
        self.active: set[tuple[int, int]] = set()  # (client id, channel id)
        self.topics: set[str] = set()  # every topic a viewer has subscribed to

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        with self.lock:
            self.active.add((client.id, channel.id))
            self.topics.add(channel.topic)
            self.lock.notify_all()

    def on_unsubscribe(self, client: Client, channel: ChannelView) -> None:
        with self.lock:
            self.active.discard((client.id, channel.id))
            self.lock.notify_all()


class LiveServer:
    """Foxglove's WebSocket server fed from a bounded queue by its own thread."""

    def __init__(
        self,
        scenario: Scenario,
        port: int,
        gate: Gate | None = None,
        block: bool = False,
        queue_limit: int = QUEUE_LIMIT,
        name: str = "formation",
    ) -> None:
        """``gate``: checks netem's decisions before they are shown (None: already checked)."""
        self.period_ns = round(scenario.control.period_s * 1e9)
        self.gate, self.block, self.limit = gate, block, queue_limit
        self.offered = self.sent = self.dropped = self.skipped = 0
        self.epoch = -1  # newest epoch whose scene or metrics went out
        self._queue: deque[tuple[str, str, bytes]] = deque()
        self._cond = threading.Condition()
        self._closing = False
        self._subs = _Subscriptions()
        # The channels exist before the server: a viewer connecting at once sees them all (a
        # channel made while a viewer connects was advertised but unknown to its subscribe).
        ctx = self._context = foxglove.Context()
        self._scene = _channel(SCENE_TOPIC, "scene", ctx)
        self._tf = FrameTransformsChannel(TF_TOPIC, context=ctx)
        self._log = _channel(LOG_TOPIC, "log", ctx)
        self._metrics = foxglove.Channel(
            METRICS_TOPIC,
            schema=_schema(model_schema(EpochMetrics)),
            message_encoding="json",
            context=ctx,
        )
        self._decisions = foxglove.Channel(
            DECISIONS_TOPIC,
            schema=_schema(model_schema(DecisionBatch)),
            message_encoding="json",
            context=ctx,
        )
        self._stats = foxglove.Channel(STATS_TOPIC, schema=STATS_SCHEMA, context=ctx)
        try:
            self.server = foxglove.start_server(
                name=name,
                host=HOST,
                port=port,
                context=ctx,
                capabilities=[Capability.Time],
                server_listener=self._subs,
                message_backlog_size=BACKLOG,
            )
        except RuntimeError as exc:  # FoxgloveError: the port is taken, or not ours to bind
            raise TestbedError(f"--foxglove {port}: cannot serve on {HOST}:{port}: {exc}") from None
        self.port = self.server.port
        self._thread = threading.Thread(target=self._serve, name="recorder-live", daemon=True)

    def start(self) -> LiveServer:
        """Start sending; until then offered messages wait (the oldest dropped past the limit)."""
        self._thread.start()
        return self

    @property
    def url(self) -> str:
        return f"ws://{HOST}:{self.port}"

    # -- the producer's side (the recorder's writer thread, the replay) ----------------------
    def offer(self, kind: str, key: str, payload: bytes) -> None:
        """Queue a message of channel ``kind`` on ``key`` (:data:`LIVE_KINDS`; others are ignored)."""
        if kind not in LIVE_KINDS:
            return
        with self._cond:
            self.offered += 1
            if self.block:
                while len(self._queue) >= self.limit and not self._closing:
                    self._cond.wait()
            elif len(self._queue) >= self.limit:
                self._queue.popleft()
                self.dropped += 1
            self._queue.append((kind, key, payload))
            self._cond.notify_all()

    def wait_for_viewer(self, timeout_s: float) -> bool:
        """Wait until a viewer has subscribed to the scene; False on timeout."""
        return self.wait_for_topics({SCENE_TOPIC}, timeout_s)

    def wait_for_topics(self, topics: set[str], timeout_s: float) -> bool:
        """Wait until viewers have subscribed to every one of ``topics``; False on timeout."""
        deadline = time.monotonic() + timeout_s
        with self._subs.lock:
            while not topics <= self._subs.topics:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._subs.lock.wait(left)
        return True

    def finish(self) -> None:
        """Send everything queued and end the server's thread (the server stays up)."""
        with self._cond:
            self._closing = True
            self._cond.notify_all()
        if self._thread.ident is None:
            self._thread.start()  # never started: send what waits, then end
        self._thread.join()

    def close(self, linger_s: float = LINGER_S) -> None:
        """:meth:`finish`, let viewers take the last messages (up to ``linger_s``), stop."""
        self.finish()
        deadline = time.monotonic() + linger_s
        with self._subs.lock:
            while self._subs.active and (left := deadline - time.monotonic()) > 0:
                self._subs.lock.wait(left)
        stopping = threading.Thread(target=self.server.stop, name="foxglove-stop", daemon=True)
        stopping.start()
        stopping.join(STOP_S)
        if stopping.is_alive():
            log.warning("a viewer that does not read held the server's stop %g s; left it", STOP_S)

    def stats(self, state: str = "running") -> dict[str, Any]:
        return {
            "state": state,
            "epoch": self.epoch,
            "offered": self.offered,
            "sent": self.sent,
            "dropped": self.dropped,
            "skipped": self.skipped,
        }

    # -- the server's thread --------------------------------------------------------------------
    def _serve(self) -> None:
        try:
            self._serve_queue()
        finally:  # ended, or failed: a blocked producer must not wait for it
            with self._cond:
                self._closing = True
                self._cond.notify_all()

    def _serve_queue(self) -> None:
        next_stats = time.monotonic()
        while True:
            with self._cond:
                if not self._queue and not self._closing:
                    self._cond.wait(STATS_PERIOD_S)
                items = list(self._queue)
                self._queue.clear()
                self._cond.notify_all()
                done = self._closing and not items
            for kind, key, payload in items:
                try:
                    self._send(kind, key, payload)
                except (ValueError, KeyError, TypeError, IndexError, DecodeError) as exc:
                    self.skipped += 1  # never the recorder's own output; a forged one at worst
                    log.warning("live view: a %s message not shown: %s", kind, exc)
            if done:
                self._stats.log(orjson.dumps(self.stats("done")), log_time=self._now())
                return
            if time.monotonic() >= next_stats:
                self._stats.log(orjson.dumps(self.stats()), log_time=self._now())
                next_stats = time.monotonic() + STATS_PERIOD_S

    def _now(self) -> int:
        return max(self.epoch, 0) * self.period_ns

    def _advance(self, epoch: int) -> int:
        """The sim time of ``epoch`` [ns]; the timeline moves when it is the newest."""
        epoch = max(epoch, 0)  # log times are unsigned
        stamp = epoch * self.period_ns
        if epoch > self.epoch:
            self.epoch = epoch
            self.server.broadcast_time(stamp)
        return stamp

    def _send(self, kind: str, key: str, payload: bytes) -> None:
        if kind == "scene":
            self._scene.log(payload, log_time=self._advance(scene_epoch(payload)))
            self.sent += 1
        elif kind == "log":
            decode_kind("log", payload)  # a forged line goes no further
            self._log.log(payload, log_time=self._now())
            self.sent += 1
        elif kind == "metrics":
            body = orjson.loads(payload)
            stamp = self._advance(int(body["epoch"]))
            self._metrics.log(payload, log_time=stamp)
            self._tf.log(frame_transforms(body["positions"], stamp), log_time=stamp)
            self.sent += 2
        elif kind == "decision":
            if self.gate is not None and self.gate.check(key, payload, "decision") is None:
                self.skipped += 1
                return
            epoch = int(orjson.loads(payload)["epoch"])
            self._decisions.log(payload, log_time=max(epoch, 0) * self.period_ns)
            self.sent += 1


__all__ = [
    "DECISIONS_TOPIC",
    "HOST",
    "LINGER_S",
    "LIVE_KINDS",
    "LOG_TOPIC",
    "METRICS_TOPIC",
    "QUEUE_LIMIT",
    "SCENE_TOPIC",
    "STATS_TOPIC",
    "TF_TOPIC",
    "LiveServer",
    "scene_epoch",
]
