"""Realtime receivers take a deadline's messages in one wake-up (``Service.take_by``), over a
real Zenoh session: what was queued by the deadline is routed, what came after is held."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import pytest

from shell import Incoming, Publisher, Service
from testkit.zenoh_peer import peer_service

pytestmark = pytest.mark.integration
RUN = "take-by"


def wait_for(cond, timeout_s: float = 10.0) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


@contextmanager
def probe(ident: int) -> Iterator[tuple[Service, Publisher, str]]:
    """A peer service subscribed to a key of its own, and a publisher on that key."""
    with peer_service(RUN, "agent", ident) as svc:
        key = f"{RUN}/probe/{ident}"
        svc.subscribe(key)
        pub = svc.bus.declare_publisher(key)
        try:
            yield svc, pub, key
        finally:
            pub.undeclare()


def test_routes_what_came_by_the_deadline_and_holds_the_rest() -> None:
    with probe(1) as (svc, pub, key):
        routed: list[bytes] = []
        pub.put(b"in time")
        wait_for(lambda: svc.inbox.qsize() == 1)
        deadline = time.time_ns() + int(0.3e9)
        early = Incoming(key, b"held from before", None, deadline - 1)

        def put_late() -> None:
            time.sleep(max(0.0, (deadline - time.time_ns()) / 1e9 + 0.05))
            pub.put(b"late")

        sender = threading.Thread(target=put_late)
        sender.start()
        slept = time.monotonic()
        held = svc.take_by(deadline, lambda m: routed.append(m.payload), [early])
        slept = time.monotonic() - slept
        sender.join()
        assert routed == [b"held from before", b"in time"]
        assert slept > 0.25  # one wake-up, at the deadline, not at the first message
        # queued by the time it woke (a late wake-up), or still to come: held either way
        wait_for(lambda: bool(held) or svc.inbox.qsize() == 1)
        assert [m.payload for m in held] in ([], [b"late"])
        later = svc.take_by(time.time_ns(), lambda m: routed.append(m.payload), held)
        assert routed == [b"held from before", b"in time", b"late"] and later == []


def test_returns_at_once_when_stopping() -> None:
    with peer_service(RUN, "agent", 2) as svc:
        svc.stopping.set()
        started = time.monotonic()
        assert svc.take_by(time.time_ns() + int(30e9), lambda m: None, []) == []
        assert time.monotonic() - started < 10.0


def test_with_complete_it_returns_once_complete_and_leaves_the_rest_queued() -> None:
    with probe(3) as (svc, pub, _):
        routed: list[bytes] = []
        deadline = time.time_ns() + int(20e9)
        for payload in (b"first", b"second", b"after"):
            pub.put(payload)
        wait_for(lambda: svc.inbox.qsize() == 3)
        started = time.monotonic()
        held = svc.take_by(deadline, lambda m: routed.append(m.payload), [],
                           complete=lambda: len(routed) == 2)  # fmt: skip
        assert time.monotonic() - started < 10.0, "it returned once complete, not at the deadline"
        assert routed == [b"first", b"second"] and held == []
        assert svc.inbox.qsize() == 1  # the next phase's, still queued


def test_with_complete_it_still_stops_at_the_deadline() -> None:
    with probe(4) as (svc, pub, _):
        routed: list[bytes] = []
        pub.put(b"only one")
        wait_for(lambda: svc.inbox.qsize() == 1)
        deadline = time.time_ns() + int(0.3e9)
        held = svc.take_by(deadline, lambda m: routed.append(m.payload), [],
                           complete=lambda: len(routed) == 2)  # fmt: skip
        assert time.time_ns() >= deadline, "nothing more came: it waited for the deadline"
        assert routed == [b"only one"] and held == []
