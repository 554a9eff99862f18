"""A service on the bus: publishers, subscribers, liveliness, the start barrier.

A :class:`Service` talks only to a :class:`~shell.bus.Bus` (Zenoh in the product, memory
in unit tests); the signals are :func:`shell.serving.serve`'s. Incoming samples go into one
queue that the service's main thread drains, in arrival order; or, when a node sets
:attr:`Service.inline`, they are handled on the bus's receiving thread under
:attr:`Service.inline_lock`. Either way one handler runs at a time.
"""

from __future__ import annotations

import contextlib
import gc
import logging
import queue
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import orjson
import zenoh
from pydantic import BaseModel

from formation import keys
from formation.codec import Malformed, encode, now_ns
from formation.errors import PluginFailure, RuntimeFailure
from formation.messages import Status
from shell.bus import Bus, Publisher, Query, Sample, ZenohBus

log = logging.getLogger("service")


@dataclass(frozen=True)
class Incoming:
    key: str
    payload: bytes
    attachment: bytes | None
    arrived_ns: int = 0  # wall time it was queued (realtime: late by scheduling or on the way)


def settle_heap() -> None:
    """Keep what setup allocated out of the garbage collector's sight for the rest of the run.

    The scenario, models and Zenoh objects live until exit; tracing them again on every
    full collection cost the leader a quarter of its CPU at 1,000 agents. The young
    generation is then let grow to 100,000 objects (700 by default): an epoch's messages
    die young, and collected every 700 allocations they survived into the older
    generations, whose collections took about a quarter of netem's CPU at 1,000 pooled agents.
    Full collections still come, every 50 million allocations.
    """
    gc.collect()
    gc.freeze()
    gc.set_threshold(YOUNG_OBJECTS, 50, 10)


YOUNG_OBJECTS = 100_000


class Service:
    """A process of role ``role`` and id ``ident`` in run ``run_id``, on ``bus``.

    ``start_timeout_s``: how long :meth:`wait_started` waits for netem's start (None: for ever).
    """

    def __init__(
        self,
        bus: Bus,
        run_id: str,
        role: str,
        ident: int | str,
        *,
        start_timeout_s: float | None = None,
    ) -> None:
        self.bus = bus
        self.run_id, self.role, self.ident = run_id, role, ident
        self.name = f"{role}/{ident}" if role in ("agent", "pool") else role
        self.start_timeout_s = start_timeout_s
        self.inbox: queue.SimpleQueue[Incoming] = queue.SimpleQueue()
        self.stopping = threading.Event()
        self.failure: PluginFailure | None = None  # a plug-in failed in a handler: the run ends
        self.malformed = Malformed()
        self.sent: Counter[str] = Counter()
        self._seq: Counter[str] = Counter()
        self._publishers: dict[str, Publisher] = {}
        self._keep: list[Any] = []
        self._alive: set[str] = set()
        self._alive_lock = threading.Lock()
        self._started = threading.Event()
        self._missing_since: dict[tuple[str, str], int] = {}
        # When set, samples are handled at once on Zenoh's thread, under inline_lock, instead of
        # queued for the main thread: one thread wake-up less per message on the lockstep path.
        self.inline: Callable[[Incoming], None] | None = None
        self.inline_lock = threading.Lock()

    @classmethod
    def open(
        cls,
        conf: zenoh.Config,
        run_id: str,
        role: str,
        ident: int | str,
        *,
        start_timeout_s: float | None = None,
    ) -> Service:
        """A service on a new Zenoh session of ``conf`` (as zenoh-python's examples take ``conf``)."""
        return cls(ZenohBus.open(conf), run_id, role, ident, start_timeout_s=start_timeout_s)

    # -- publishing ---------------------------------------------------------------------------
    def next_seq(self, key: str) -> int:
        seq = self._seq[key]
        self._seq[key] += 1
        return seq

    def publisher(self, key: str) -> Publisher:
        """The publisher of ``key``, declared once (one that never drops: :meth:`Bus.declare_publisher`)."""
        pub = self._publishers.get(key)
        if pub is None:
            pub = self._publishers[key] = self.bus.declare_publisher(key)
        return pub

    def declare_publishers(self, keys: Iterable[str]) -> None:
        """Declare these publishers now, before the run's clock starts: declared at their first
        put, they made realtime's first epochs late (a declaration per key, all in one burst)."""
        for key in keys:
            self.publisher(key)

    def put(self, key: str, payload: Any, attachment: Any = None) -> None:
        """Publish raw bytes (or a received ``ZBytes``, forwarded without a copy) on ``key``."""
        self.publisher(key).put(payload, attachment=attachment)
        self.sent[key] += 1

    def publish(self, key: str, message: BaseModel, attachment: bytes | None = None) -> None:
        self.put(key, encode(message), attachment)

    def header(self, key: str, epoch: int) -> dict[str, Any]:
        """The common fields of a message about to be published on ``key``."""
        return {
            "run_id": self.run_id,
            "sender": self.name,
            "seq": self.next_seq(key),
            "epoch": epoch,
            "stamp_ns": now_ns(),
        }

    def header_format(self) -> bytes:
        """:meth:`header`'s fields as the opening of a JSON object, ``%d`` for ``seq``,
        ``epoch`` and ``stamp_ns`` in that order: for a publisher of thousands an epoch."""
        fixed = orjson.dumps({"run_id": self.run_id, "sender": self.name})[:-1]
        return fixed.replace(b"%", b"%%") + b',"seq":%d,"epoch":%d,"stamp_ns":%d'

    def status(
        self,
        state: str,
        epochs_done: int = 0,
        detail: str = "",
        delivered: dict[str, int] | None = None,
    ) -> None:
        key = keys.status(self.run_id, self.role, self.ident)
        msg = Status(
            **self.header(key, epochs_done - 1),
            role=self.role,
            state=state,
            epochs_done=epochs_done,
            malformed=dict(self.malformed.counts),
            sent=dict(self.sent),
            delivered=delivered or {},
            detail=detail,
        )
        self.publish(key, msg)

    # -- subscribing --------------------------------------------------------------------------
    def subscribe(
        self, key: str, callback: Callable[[Sample], None] | None = None, direct: bool = False
    ) -> None:
        """Subscribe ``key``; samples go to ``callback`` or, by default, into :attr:`inbox`.

        ``direct``: run the handler on Zenoh's receiving thread instead of a Python thread of
        the subscription's own. A pool has one subscription per agent, so hundreds of threads,
        and waking a different one for each sample cost it a fifth of its CPU.
        """

        clock = self.bus.time_ns

        def to_inbox(sample: Sample) -> None:
            att = sample.attachment
            msg = Incoming(
                str(sample.key_expr),
                sample.payload.to_bytes(),
                att.to_bytes() if att else None,
                clock(),
            )
            handler = self.inline
            if handler is None:
                self.inbox.put(msg)
            else:
                self.handle_inline(msg.key, handler, msg)

        self._keep.append(self.bus.declare_subscriber(key, callback or to_inbox, direct=direct))

    def handle_inline(self, key: str, handler: Callable[..., None], *args: Any) -> None:
        """``handler(*args)`` under :attr:`inline_lock`, for a message on ``key``.

        A bad message must never stop the process: an exception is counted and logged. A
        plug-in that failed does: it is kept in :attr:`failure` and the service stops.
        """
        with self.inline_lock:
            try:
                handler(*args)
            except PluginFailure as exc:
                if self.failure is None:
                    self.failure = exc
                self.stopping.set()
            except Exception:
                self.malformed.counts[key] += 1
                log.exception("while handling %s", key)

    def ask(self, key: str, body: dict[str, Any], timeout_s: float = 5.0) -> dict[str, Any] | None:
        """The first JSON object a queryable on ``key`` answers to ``body``; None if none does
        (an answer that is not one is counted as malformed).

        The query leaves after what this session published before it, on the same link.
        """
        for reply in self.bus.get(key, orjson.dumps(body), timeout_s):
            try:
                answer = orjson.loads(reply)
            except orjson.JSONDecodeError:
                answer = None
            if isinstance(answer, dict):
                return answer
            self.malformed.counts[key] += 1
        return None

    def queryable(self, key: str, callback: Callable[[Query], None]) -> None:
        """Answer queries on ``key`` with ``callback`` (on the bus's thread)."""
        self._keep.append(self.bus.declare_queryable(key, callback))

    # -- liveliness ---------------------------------------------------------------------------
    def announce(self, role: str | None = None, ident: int | str | None = None) -> None:
        """Declare this process (or one agent of its pool) alive, after its subscribers exist."""
        key = keys.alive(self.run_id, role or self.role, self.ident if ident is None else ident)
        self._keep.append(self.bus.declare_token(key))

    def watch_alive(self, on_change: Callable[[str, str, bool], None] | None = None) -> None:
        """Track liveliness tokens of the run; ``on_change(role, ident, alive)`` is called on a Zenoh thread."""

        def changed(key: str, alive: bool) -> None:
            with self._alive_lock:
                (self._alive.add if alive else self._alive.discard)(key)
            if key == keys.start(self.run_id) and alive:
                self._started.set()
            if on_change is not None:
                role, ident = keys.parse(key).args
                on_change(role, ident, alive)

        self._keep.append(
            self.bus.declare_liveliness_subscriber(keys.alive_all(self.run_id), changed)
        )

    def gone_for(self, role: str, ident: int | str, grace_s: float = 5.0) -> bool:
        """True once ``role/ident`` has had no liveliness token for ``grace_s`` seconds.

        A loaded machine can miss a lease for a moment; a crash stays gone.
        """
        now = now_ns()
        key = (role, str(ident))
        if self.is_alive(role, ident):
            self._missing_since.pop(key, None)
            return False
        since = self._missing_since.setdefault(key, now)
        return now - since > grace_s * 1e9

    def is_alive(self, role: str, ident: int | str) -> bool:
        with self._alive_lock:
            return keys.alive(self.run_id, role, ident) in self._alive

    def wait_started(self) -> bool:
        """Block until netem declares the start token; False when stopped.

        Raises :class:`RuntimeFailure` after ``--start-timeout`` seconds without a start.
        """
        timeout_s = self.start_timeout_s
        deadline = None if timeout_s is None else now_ns() + int(timeout_s * 1e9)
        asked = now_ns()
        while not self.stopping.is_set():
            if self._started.wait(0.05):
                settle_heap()
                return True
            if now_ns() - asked > 1_000_000_000:  # a token declared before this process
                asked = now_ns()  # subscribed may never show there: ask for it, each second
                if next(self.bus.tokens(keys.start(self.run_id), 0.2), None) is not None:
                    self._started.set()
            if deadline is not None and now_ns() > deadline:
                raise RuntimeFailure(
                    f"{self.name}: no start from netem within {timeout_s:g} s (is netem running and reachable?)"
                )
        return False

    def run_started(self, timeout_s: float = 0.5) -> bool:
        """Whether netem declared the start already: asked before this process announces itself,
        True means it was restarted into a running run (netem waits for every process first).

        Asked again for ``timeout_s``: a liveliness query right after the session opens can
        come back empty, about one time in three (seen with zenoh 1.x in client mode).
        """
        deadline = now_ns() + int(timeout_s * 1e9)
        while True:
            started = next(self.bus.tokens(keys.start(self.run_id), timeout_s), None)
            if started is not None or self._started.is_set():
                return True
            if now_ns() > deadline or self.stopping.wait(0.05):
                return False

    def seen_now(self, role: str, ident: int | str) -> None:
        """Forget since when ``role/ident`` was missing: it is back, its token on its way."""
        self._missing_since.pop((role, str(ident)), None)

    def declare_start(self) -> None:
        """netem's start token: the run's clock is about to start."""
        self._keep.append(self.bus.declare_token(keys.start(self.run_id)))

    def next_incoming(self, timeout_s: float = 0.1) -> Incoming | None:
        try:
            return self.inbox.get(timeout=timeout_s)
        except queue.Empty:
            return None

    def take_by(
        self,
        t_ns: int,
        route: Callable[[Incoming], None],
        held: list[Incoming],
        complete: Callable[[], bool] | None = None,
    ) -> list[Incoming]:
        """Realtime: route ``held``, sleep until ``t_ns``, then route what was queued by then.

        Returns what was queued later, for the caller to route once it has taken this
        deadline's epoch. One wake-up per deadline, not one per message: a message queued in
        time is in time however late this thread wakes (else the miss is ``scheduling``).
        With ``complete`` (nothing more the caller would take can come once it holds), it
        wakes per message instead, and returns as soon as ``complete()``: what the deadline
        would give, sooner.
        """
        for early in held:
            route(early)
        clock = self.bus.time_ns
        if complete is None and (left := (t_ns - clock()) / 1e9) > 0:
            self.stopping.wait(left)
        while not (complete is not None and complete()):
            msg = self.next_incoming(0 if complete is None else max(0.0, (t_ns - clock()) / 1e9))
            if msg is None:
                return []
            if msg.arrived_ns > t_ns:
                return [msg]  # the queue is in order: the rest came later still
            route(msg)
        return []

    def close(self) -> None:
        for obj in reversed(self._keep):
            with contextlib.suppress(Exception):
                obj.undeclare()
        self._keep.clear()
        for pub in self._publishers.values():
            pub.undeclare()
        self._publishers.clear()
        self.bus.close()


def drain_last(
    service: Service,
    route: Callable[[Incoming], None],
    timeout_s: float = 5.0,
    settle_s: float = 0.1,
) -> None:
    """After the last epoch, route what still comes until netem has gone (it forwards every
    packet due before it leaves; at most ``timeout_s``), then until nothing has come for
    ``settle_s``: a packet still on its way when the run ends is counted as a miss, not left
    out of the books. The quiet period restarts with each message, so a backlog still queued
    when netem's token goes (a busy receiver, or the token overtaking data) is all routed."""
    end = time.monotonic() + timeout_s
    while service.is_alive("netem", 0) and time.monotonic() < end:
        if (msg := service.next_incoming(0.02)) is not None:
            route(msg)
    while time.monotonic() < end + timeout_s:
        if (msg := service.next_incoming(settle_s)) is None:
            return
        route(msg)
