"""The transport seam: what a service does on Zenoh, as a protocol (docs/architecture.md "Layers").

:class:`Bus` is all a :class:`~shell.service.Service` asks of the network: publishers,
subscribers, queryables and queries, liveliness tokens and their subscribers, and the
wall clock that stamps arrivals. :class:`ZenohBus` is the product's, over a
``zenoh.Session``; :class:`MemoryBus` runs node logic in one process without a network,
for unit tests (every feature is also tested between real processes).
"""

from __future__ import annotations

import ctypes
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import zenoh


class Payload(Protocol):
    """Bytes as a sample carries them (``zenoh.ZBytes``, or :class:`MemoryBytes`)."""

    def to_bytes(self) -> bytes: ...


class Sample(Protocol):
    """A received sample: ``str(key_expr)`` is its key."""

    @property
    def key_expr(self) -> object: ...
    @property
    def payload(self) -> Payload: ...
    @property
    def attachment(self) -> Payload | None: ...
    @property
    def timestamp(self) -> Any:
        """The sender's timestamp (``zenoh.Timestamp``) when its session stamps, else None."""
        ...


class Query(Protocol):
    """A query to a queryable, answered by :meth:`reply` or :meth:`reply_err`."""

    @property
    def key_expr(self) -> object: ...
    @property
    def payload(self) -> Payload | None: ...
    def reply(self, key_expr: Any, payload: Any) -> Any: ...
    def reply_err(self, payload: Any) -> Any: ...


class Publisher(Protocol):
    """A declared publisher of one key."""

    def put(self, payload: Any, *, attachment: Any = None) -> Any: ...
    def undeclare(self) -> Any: ...


class Declared(Protocol):
    """Anything declared on a bus (a subscriber, queryable or token) until undeclared."""

    def undeclare(self) -> Any: ...


class Bus(Protocol):
    """What a service calls on the network; ``key`` arguments are key expressions."""

    def declare_publisher(self, key: str) -> Publisher:
        """A publisher of ``key`` that never drops (it blocks under congestion)."""
        ...

    def declare_subscriber(
        self, key: str, callback: Callable[[Sample], None], *, direct: bool = False
    ) -> Declared:
        """``callback(sample)`` for every sample on ``key``; ``direct``: on the receiving thread."""
        ...

    def declare_queryable(self, key: str, callback: Callable[[Query], None]) -> Declared:
        """``callback(query)`` for every query on ``key``."""
        ...

    def get(
        self, key: str, payload: bytes | None = None, timeout_s: float = 5.0
    ) -> Iterator[bytes]:
        """Query ``key``: the payloads of the good replies, as they come (errors skipped)."""
        ...

    def declare_token(self, key: str) -> Declared:
        """A liveliness token of ``key``, alive until undeclared (or the process ends)."""
        ...

    def declare_liveliness_subscriber(
        self, key: str, callback: Callable[[str, bool], None], *, history: bool = True
    ) -> Declared:
        """``callback(token_key, alive)`` as tokens on ``key`` appear and go; ``history``:
        the tokens alive now first."""
        ...

    def tokens(self, key: str, timeout_s: float) -> Iterator[str]:
        """The liveliness tokens alive on ``key`` now, as the answers come (a liveliness query)."""
        ...

    def time_ns(self) -> int:
        """Wall time [ns] (arrival stamps, realtime deadlines)."""
        ...

    def close(self) -> None:
        """Close the connection; what was declared on it is gone."""
        ...


class ZenohBus:
    """The product's bus: one ``zenoh.Session``."""

    def __init__(self, session: zenoh.Session) -> None:
        self.session = session

    @classmethod
    def open(cls, conf: zenoh.Config) -> ZenohBus:
        """A bus of a new session of ``conf`` (``shell.zenoh_config.session_config``)."""
        return cls(zenoh.open(conf))

    def declare_publisher(self, key: str) -> Publisher:
        """BLOCK: a publisher never silently drops what netem is meant to decide on. Not
        express: zenoh still sends at once when its queue is idle, but batches a burst
        (netem's fan-out) into few writes; express cost netem 5x its forwarding rate."""
        return self.session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)

    def declare_subscriber(
        self, key: str, callback: Callable[[Sample], None], *, direct: bool = False
    ) -> Declared:
        """``direct``: the handler runs on Zenoh's receiving thread instead of a Python
        thread of the subscription's own."""
        if not direct:
            return self.session.declare_subscriber(key, callback)
        handler = zenoh.handlers.Callback(_OnZenohThread(callback), indirect=False)
        return self.session.declare_subscriber(key, handler)

    def declare_queryable(self, key: str, callback: Callable[[Query], None]) -> Declared:
        return self.session.declare_queryable(key, callback)

    def get(
        self, key: str, payload: bytes | None = None, timeout_s: float = 5.0
    ) -> Iterator[bytes]:
        replies = (
            self.session.get(key, timeout=timeout_s)
            if payload is None
            else self.session.get(key, payload=payload, timeout=timeout_s)
        )
        for reply in replies:
            if reply.ok is not None:
                yield reply.ok.payload.to_bytes()

    def declare_token(self, key: str) -> Declared:
        return self.session.liveliness().declare_token(key)

    def declare_liveliness_subscriber(
        self, key: str, callback: Callable[[str, bool], None], *, history: bool = True
    ) -> Declared:
        def changed(sample: zenoh.Sample) -> None:
            callback(str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)

        return self.session.liveliness().declare_subscriber(key, changed, history=history)

    def tokens(self, key: str, timeout_s: float) -> Iterator[str]:
        for reply in self.session.liveliness().get(key, timeout=timeout_s):
            if reply.ok is not None:
                yield str(reply.ok.key_expr)

    def time_ns(self) -> int:
        return time.time_ns()

    def close(self) -> None:
        self.session.close()


class _OnZenohThread:
    """A callback run on Zenoh's own receiving threads, which Python does not know: around
    each call zenoh-python takes the GIL by ``PyGILState_Ensure`` and lets it go by
    ``PyGILState_Release``, which create and destroy the thread's Python state every time
    unless the thread holds one already. So the first call on each thread keeps one, for
    the life of the process (one per Zenoh thread; the session is closed before exit)."""

    def __init__(self, callback: Callable[[Sample], None]) -> None:
        self.callback = callback

    def __call__(self, sample: Sample) -> None:
        if threading.get_ident() not in _KEPT:
            _keep_thread_state()
        self.callback(sample)


_KEPT: set[int] = set()  # the threads whose Python state is kept


def _keep_thread_state() -> None:
    """Hold this thread's Python state once more, never released (call with the GIL held)."""
    ctypes.pythonapi.PyGILState_Ensure()
    _KEPT.add(threading.get_ident())


class MemoryBytes(bytes):
    """Bytes with ``ZBytes.to_bytes``: a :class:`MemoryBus` sample's payload."""

    def to_bytes(self) -> bytes:
        return bytes(self)


def _as_bytes(payload: Any) -> MemoryBytes:
    return MemoryBytes(payload if isinstance(payload, bytes | bytearray) else payload.to_bytes())


@dataclass(frozen=True)
class MemorySample:
    """A sample on a :class:`MemoryBus`."""

    key_expr: str
    payload: MemoryBytes
    attachment: MemoryBytes | None = None
    timestamp: None = None


@dataclass
class MemoryQuery:
    """A query on a :class:`MemoryBus`; its replies are collected in :attr:`replies`."""

    key_expr: str
    payload: MemoryBytes | None
    replies: list[bytes | None]

    def reply(self, key_expr: Any, payload: Any) -> None:
        self.replies.append(bytes(_as_bytes(payload)))

    def reply_err(self, payload: Any) -> None:
        self.replies.append(None)


class _Declaration:
    def __init__(self, undeclare: Callable[[], None]) -> None:
        self._undeclare: Callable[[], None] | None = undeclare

    def undeclare(self) -> None:
        undo, self._undeclare = self._undeclare, None
        if undo is not None:
            undo()


class _MemoryPublisher:
    def __init__(self, bus: MemoryBus, key: str) -> None:
        self.bus, self.key = bus, key

    def put(self, payload: Any, *, attachment: Any = None) -> None:
        self.bus.put(self.key, payload, attachment=attachment)

    def undeclare(self) -> None:
        pass


class MemoryBus:
    """An in-process bus for unit tests: every callback runs at once on the thread that
    published (or queried, or declared the token), so a test's effects are done when its
    call returns. Key expressions (``*``, ``**``) are matched as Zenoh matches them
    (``zenoh.KeyExpr.intersects``, which needs no session). Several services may share one.
    """

    def __init__(self, clock: Callable[[], int] = time.time_ns) -> None:
        self.clock = clock
        self.puts: Counter[str] = Counter()  # per key, everything published
        self._lock = threading.Lock()
        self._ids = 0
        self._subscribers: dict[int, tuple[zenoh.KeyExpr, Callable[[Sample], None]]] = {}
        self._queryables: dict[int, tuple[zenoh.KeyExpr, Callable[[Query], None]]] = {}
        self._tokens: Counter[str] = Counter()
        self._watchers: dict[int, tuple[zenoh.KeyExpr, Callable[[str, bool], None]]] = {}

    def _add(self, table: dict[int, Any], entry: Any) -> Declared:
        with self._lock:
            self._ids += 1
            ident = self._ids
            table[ident] = entry
        return _Declaration(lambda: self._remove(table, ident))

    def _remove(self, table: dict[int, Any], ident: int) -> None:
        with self._lock:
            table.pop(ident, None)

    @staticmethod
    def _matching(table: dict[int, tuple[zenoh.KeyExpr, Any]], key: str) -> list[Any]:
        expr = zenoh.KeyExpr(key)
        return [callback for ke, callback in list(table.values()) if ke.intersects(expr)]

    def put(self, key: str, payload: Any, *, attachment: Any = None) -> None:
        """Deliver ``payload`` on ``key`` to every matching subscriber, now."""
        sample = MemorySample(
            key, _as_bytes(payload), None if attachment is None else _as_bytes(attachment)
        )
        self.puts[key] += 1
        for callback in self._matching(self._subscribers, key):
            callback(sample)

    def declare_publisher(self, key: str) -> Publisher:
        return _MemoryPublisher(self, key)

    def declare_subscriber(
        self, key: str, callback: Callable[[Sample], None], *, direct: bool = False
    ) -> Declared:
        return self._add(self._subscribers, (zenoh.KeyExpr(key), callback))

    def declare_queryable(self, key: str, callback: Callable[[Query], None]) -> Declared:
        return self._add(self._queryables, (zenoh.KeyExpr(key), callback))

    def get(
        self, key: str, payload: bytes | None = None, timeout_s: float = 5.0
    ) -> Iterator[bytes]:
        replies: list[bytes | None] = []
        body = None if payload is None else MemoryBytes(payload)
        for callback in self._matching(self._queryables, key):
            callback(MemoryQuery(key, body, replies))
        return iter([r for r in replies if r is not None])

    def declare_token(self, key: str) -> Declared:
        with self._lock:
            self._tokens[key] += 1
        self._changed(key, True)

        def gone() -> None:
            with self._lock:
                self._tokens[key] -= 1
                if not self._tokens[key]:
                    del self._tokens[key]
            self._changed(key, False)

        return _Declaration(gone)

    def _changed(self, key: str, alive: bool) -> None:
        for callback in self._matching(self._watchers, key):
            callback(key, alive)

    def declare_liveliness_subscriber(
        self, key: str, callback: Callable[[str, bool], None], *, history: bool = True
    ) -> Declared:
        declared = self._add(self._watchers, (zenoh.KeyExpr(key), callback))
        if history:
            for token in self.tokens(key, 0.0):
                callback(token, True)
        return declared

    def tokens(self, key: str, timeout_s: float) -> Iterator[str]:
        expr = zenoh.KeyExpr(key)
        with self._lock:
            alive = list(self._tokens)
        return iter([t for t in alive if zenoh.KeyExpr(t).intersects(expr)])

    def time_ns(self) -> int:
        return self.clock()

    def close(self) -> None:
        """Nothing to close: each service undeclares its own on close."""


if TYPE_CHECKING:  # both are buses (mypy checks the protocol here)

    def _are_buses(zenoh_bus: ZenohBus, memory_bus: MemoryBus) -> tuple[Bus, Bus]:
        return zenoh_bus, memory_bus
