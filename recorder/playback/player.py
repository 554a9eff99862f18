"""``formation replay``: a recording published back onto Zenoh with its original timing.

Messages go out in log-time order, message ``m`` at ``t0 + (log_m − log_first) / rate``
of the wall clock. ``--prefix`` replaces the recorded ``formation/<run_id>`` so a
fresh process can consume the traffic under another run id. The codec attachment
``(epoch, seq, source)`` is not stored in MCAP; it is rebuilt from the payload
(``source`` = the ``agent`` field, or the leader's endpoint for estimates).
Liveliness logs are not replayed (a put is not a token). A message that does not
validate or whose sender does not own its key (:mod:`recorder.reading.trust`) is not replayed
either; each pass counts them in :attr:`Replayer.skipped`.

With ``--foxglove PORT`` the replay goes to Foxglove instead of Zenoh: the recorded
scenes, log lines, metrics and decisions are served as a live run is (:mod:`recorder.live.server`):
the recorded bytes (protobuf for the scene and the log, with the SDK's schema the recording
carries), nothing dropped, from when a viewer subscribes to the scene. A scene or log line
that does not decode is counted and skipped by the trust gate like any malformed message.

A running replay answers on ``<prefix>/replay/control`` (a queryable): the query's
parameters or JSON payload give ``command`` = ``pause``, ``resume``, ``seek``
(``value`` seconds from the start of the recording), ``rate`` (``value``) or
``status``; the reply is the state as JSON.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import zenoh

from formation import codec, keys
from formation.errors import TestbedError
from recorder.live.server import LiveServer
from recorder.reading.reader import iter_messages, metadata, open_recording, scenario_of
from recorder.reading.trust import Gate, Skipped
from recorder.recording.schemas import FOXGLOVE, classify, derived_channels, run_id_of
from shell import open_session

SKIP = frozenset({"alive"})  # channel kinds never replayed
WAIT_SLICE_S = 0.05  # longest sleep between control checks [s]
LEADER_KINDS = frozenset({"leader_estimate", "agent_estimate", "link_estimate"})


def control_key(prefix: str) -> str:
    """The replay's control queryable under a run prefix ``formation/<run_id>``."""
    return keys.replay_control(prefix)


@dataclass
class State:
    """What a running replay reports; times in seconds from the recording's first message."""

    paused: bool = False
    rate: float = 1.0
    position_s: float = 0.0
    published: int = 0
    skipped: int = 0  # messages of this pass not trusted (recorder.reading.trust), not published
    loops: int = 0
    done: bool = False


def rebuild_attachment(kind: str, payload: bytes) -> bytes | None:
    """The codec attachment ``(epoch, seq, source)`` of a recorded payload, if it had one."""
    if kind in SKIP or kind in FOXGLOVE or kind == "unknown":
        return None  # the recorder's protobuf messages never had one
    try:
        body = json.loads(payload)
        epoch, seq = int(body["epoch"]), int(body["seq"])
    except (ValueError, KeyError, TypeError):
        return None
    if kind in LEADER_KINDS:  # before "agent": an agent's estimate comes from the leader
        return codec.attachment(epoch, seq, keys.LEADER_ENDPOINT)
    if isinstance(body.get("agent"), int):
        return codec.attachment(epoch, seq, body["agent"])
    return None


class Replayer:
    """Publishes a recording; :meth:`command` changes a running replay (thread-safe)."""

    def __init__(
        self,
        path: Path,
        rate: float = 1.0,
        loop: bool = False,
        start_s: float = 0.0,
        topics: list[str] | None = None,
        prefix: str | None = None,
        paused: bool = False,
    ) -> None:
        if rate <= 0:
            raise TestbedError(f"--rate {rate}; expected > 0")
        self.path, self.loop = Path(path), loop
        self.state = State(paused=paused, rate=rate, position_s=start_s)
        self._filters = [zenoh.KeyExpr(t) for t in topics or []]
        self._lock = threading.Lock()
        self._changed = threading.Event()
        self._seek: float | None = start_s
        self._base_wall = 0.0  # [s] monotonic
        self._base_log: int | None = None  # [ns] log time published at _base_wall
        with open_recording(self.path) as (reader, summary):
            self.scenario = scenario_of(metadata(reader), self.path)
            self.derived = derived_channels(summary.channels)
            self.skipped = Skipped()
            self.channels = {
                cid: ch
                for cid, ch in summary.channels.items()
                if self._wanted(ch.topic, ch.metadata)
            }
            stats = summary.statistics
            self.first_ns = stats.message_start_time if stats else 0
            self.duration_s = (stats.message_end_time - self.first_ns) / 1e9 if stats else 0.0
        recorded = sorted(r for ch in summary.channels.values() if (r := run_id_of(ch.topic)))
        self.recorded_prefix = keys.prefix(recorded[0]) if recorded else keys.ROOT
        self.prefix = prefix or self.recorded_prefix

    def _wanted(self, topic: str, metadata: dict[str, str]) -> bool:
        if metadata.get("kind", classify(topic)) in SKIP:
            return False
        key = zenoh.KeyExpr(topic)
        return not self._filters or any(f.intersects(key) for f in self._filters)

    def out_key(self, topic: str) -> str:
        return keys.moved(topic, self.recorded_prefix, self.prefix)

    # -- control ----------------------------------------------------------------------------
    # Timing: message at log time ``t`` is due at ``base_wall + (t − base_log) / rate``.
    # Pause, resume and rate changes move the anchor so the replay continues where it is;
    # a seek clears it so the next message is due at once.
    def _virtual_log(self) -> int:
        """The log time [ns] that corresponds to now (with the lock held)."""
        if self._base_log is None:
            return self.first_ns
        if self.state.paused:
            return self._base_log
        return self._base_log + int((time.monotonic() - self._base_wall) * 1e9 * self.state.rate)

    def command(self, command: str, value: float | None = None) -> State:
        with self._lock:
            if command == "pause" and not self.state.paused:
                self._base_log, self._base_wall = self._virtual_log(), time.monotonic()
                self.state.paused = True
            elif command == "resume" and self.state.paused:
                self._base_wall = time.monotonic()
                self.state.paused = False
            elif command == "seek":
                if value is None or value < 0:
                    raise TestbedError(f"seek needs a value in seconds >= 0, got {value}")
                self._seek, self._base_log = float(value), None
            elif command == "rate":
                if value is None or value <= 0:
                    raise TestbedError(f"rate needs a value > 0, got {value}")
                self._base_log, self._base_wall = self._virtual_log(), time.monotonic()
                self.state.rate = float(value)
            elif command not in ("status", "pause", "resume"):
                raise TestbedError(
                    f"unknown command {command!r}; expected pause, resume, seek, rate or status"
                )
            self._changed.set()
            return State(**asdict(self.state))

    def on_query(self, query: zenoh.Query) -> None:
        """The control queryable: parameters ``?command=seek;value=3`` or a JSON payload."""
        given = query.parameters
        params: dict[str, Any] = {k: given.get(k) for k in ("command", "value") if k in given}
        if query.payload is not None and query.payload.to_bytes():
            try:
                params.update(json.loads(query.payload.to_bytes()))
            except ValueError:
                query.reply_err(b"payload is not JSON")
                return
        try:
            value = params.get("value")
            state = self.command(
                str(params.get("command", "status")), None if value is None else float(value)
            )
        except (TestbedError, ValueError) as exc:
            query.reply_err(str(exc).encode())
            return
        query.reply(query.key_expr, json.dumps(asdict(state)).encode())

    # -- the loop -----------------------------------------------------------------------------
    def _messages(self, from_s: float) -> Iterator[tuple[str, str, bytes, int]]:
        """The trusted messages from ``from_s`` on; a fresh gate (and skip count) per pass."""
        gate = Gate(self.scenario, self.derived)
        with self._lock:
            self.skipped, self.state.skipped = gate.skipped, 0
        with open_recording(self.path) as (reader, _):
            topics = [ch.topic for ch in self.channels.values()]
            start = self.first_ns + int(from_s * 1e9)
            for _, ch, msg in iter_messages(self.path, reader, topics=topics, starting_at=start):
                kind = ch.metadata.get("kind", classify(ch.topic))
                if gate.check(ch.topic, msg.data, kind, ch.id) is None:
                    with self._lock:
                        self.state.skipped += 1
                    continue
                yield kind, ch.topic, msg.data, msg.log_time

    def run(
        self, publish: Callable[[str, bytes, bytes | None], None], stop: threading.Event
    ) -> State:
        """Publish until the end (or forever with ``loop``) or until ``stop`` is set."""
        while not stop.is_set():
            with self._lock:
                from_s, self._seek, self._base_log = self._seek or 0.0, None, None
            interrupted = False
            for kind, topic, data, log_ns in self._messages(from_s):
                if not self._wait_until(log_ns, stop):
                    interrupted = True
                    break
                publish(self.out_key(topic), data, rebuild_attachment(kind, data))
                with self._lock:
                    self.state.published += 1
            if interrupted:
                continue  # a seek restarts the pass; a stop ends the loop
            with self._lock:
                self.state.loops += 1
                if not self.loop:
                    self.state.done = True
                    break
        with self._lock:
            return State(**asdict(self.state))

    def _wait_until(self, log_ns: int, stop: threading.Event) -> bool:
        """Sleep until ``log_ns`` is due; False if stopped or a seek was asked for."""
        while not stop.is_set():
            with self._lock:
                if self._seek is not None:
                    return False
                if self._base_log is None:
                    self._base_log, self._base_wall = log_ns, time.monotonic()
                self._changed.clear()
                delay = WAIT_SLICE_S
                if not self.state.paused:
                    due = self._base_wall + (log_ns - self._base_log) / 1e9 / self.state.rate
                    delay = due - time.monotonic()
                    if delay <= 0:
                        self.state.position_s = (log_ns - self.first_ns) / 1e9
                        return True
            self._changed.wait(min(delay, WAIT_SLICE_S))
        return False


def replay(args: Any) -> int:
    """``formation replay``: the CLI entry (``args`` from :mod:`testbed.cli.recorder`)."""
    if args.foxglove is not None:
        return replay_live(args)
    replayer = Replayer(
        args.recording,
        args.rate,
        args.loop,
        args.start,
        _split(args.topics),
        args.prefix,
        args.paused,
    )
    stop = threading.Event()
    session = open_session(args)
    publishers: dict[str, zenoh.Publisher] = {}

    def publish(key: str, data: bytes, attachment: bytes | None) -> None:
        pub = publishers.get(key)
        if pub is None:
            pub = publishers[key] = session.declare_publisher(
                key, congestion_control=zenoh.CongestionControl.BLOCK
            )
        pub.put(data, attachment=attachment)

    queryable = session.declare_queryable(control_key(replayer.prefix), replayer.on_query)
    how = "paused; send resume" if replayer.state.paused else f"rate {replayer.state.rate:g}"
    print(
        f"replaying {replayer.path} onto {replayer.prefix}/** ({how}); control: {control_key(replayer.prefix)}",
        flush=True,
    )
    try:
        state = replayer.run(publish, stop)
    except KeyboardInterrupt:
        stop.set()
        state = replayer.state
    finally:
        queryable.undeclare()
        for pub in publishers.values():
            pub.undeclare()
        session.close()
    print(
        f"replayed {state.published} messages from {replayer.path} onto {replayer.prefix}/** ({state.loops} passes)"
    )
    if replayer.skipped.total:
        print(f"not replayed (last pass): {replayer.skipped.describe()}")
        for topic, count in replayer.skipped.by_channel().items():
            print(f"  {topic}: {count}")
    return 0


# What a live view shows of a recording; the frames come from the metrics.
LIVE_KEYS = (keys.scene("*"), keys.log("*"), keys.metrics("*"), keys.netem_decision("*"))
VIEWER_POLL_S = 1.0  # how often the wait for a viewer checks for Ctrl-C [s]


def replay_live(args: Any) -> int:
    """``formation replay --foxglove PORT``: the recording served to Foxglove, not to Zenoh."""
    replayer = Replayer(
        args.recording, args.rate, args.loop, args.start, _split(args.topics) or list(LIVE_KEYS)
    )
    if replayer.scenario is None:
        raise TestbedError(f"{replayer.path}: no scenario stored; --foxglove needs its period_s")
    live = LiveServer(replayer.scenario, args.foxglove, block=True).start()
    stop = threading.Event()
    print(f"serving {replayer.path} to Foxglove on {live.url}; waiting for a viewer", flush=True)
    try:
        while not live.wait_for_viewer(VIEWER_POLL_S):
            pass
        state = replayer.run(lambda key, data, _: live.offer(classify(key), key, data), stop)
    except KeyboardInterrupt:
        stop.set()
        state = replayer.state
    finally:
        live.close()
    print(
        f"served {state.published} messages from {replayer.path} on {live.url} "
        f"({state.loops} passes, {live.sent} sent)"
    )
    return 0


def _split(value: str | None) -> list[str] | None:
    return [v.strip() for v in value.split(",") if v.strip()] if value else None


__all__ = [
    "LIVE_KEYS",
    "Replayer",
    "State",
    "control_key",
    "rebuild_attachment",
    "replay",
    "replay_live",
]
