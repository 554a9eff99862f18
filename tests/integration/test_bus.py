"""ZenohBus does what MemoryBus does (tests/unit/shell/test_bus.py), between two real peers
on 127.0.0.1: samples by key expression, queries, liveliness tokens with history."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import pytest

from shell import Sample, Service, session_config
from shell.bus import ZenohBus
from testkit.zenoh_peer import free_port

pytestmark = pytest.mark.integration
RUN = "bus"


def wait_for(cond: Callable[[], bool], timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def test_two_services_on_zenoh_buses() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    netem = Service(ZenohBus.open(session_config("peer", None, endpoint)), RUN, "netem", 0)
    agent = Service.open(session_config("peer", endpoint, None), RUN, "agent", 1, start_timeout_s=5)
    try:
        got: list[tuple[str, bytes, bytes | None]] = []

        def on(sample: Sample) -> None:
            att = sample.attachment
            got.append((str(sample.key_expr), sample.payload.to_bytes(), att and att.to_bytes()))

        agent.subscribe(f"formation/{RUN}/agent/*/state", on)
        agent.subscribe(f"formation/{RUN}/in")
        agent.watch_alive()
        netem.announce()
        wait_for(lambda: agent.is_alive("netem", 0))
        assert not agent.is_alive("leader", 0)
        netem.declare_start()
        assert agent.wait_started() and agent.run_started()
        netem.queryable(f"formation/{RUN}/ask", lambda q: q.reply(q.key_expr, b'{"ok": true}'))
        wait_for(lambda: agent.ask(f"formation/{RUN}/ask", {"q": 1}, timeout_s=1.0) is not None)
        assert agent.ask(f"formation/{RUN}/ask", {"q": 1}) == {"ok": True}
        netem.put(f"formation/{RUN}/agent/2/state", b"x", b"a")
        netem.put(f"formation/{RUN}/other/2/state", b"no")
        netem.put(f"formation/{RUN}/in", b"payload", b"att")
        wait_for(lambda: bool(got) and agent.inbox.qsize() == 1)
        assert got == [(f"formation/{RUN}/agent/2/state", b"x", b"a")]
        msg = agent.next_incoming(0)
        assert msg is not None and (msg.key, msg.payload, msg.attachment) == (
            f"formation/{RUN}/in",
            b"payload",
            b"att",
        )
        assert netem.sent[f"formation/{RUN}/in"] == 1
    finally:
        netem.close()
        wait_for(lambda: not agent.is_alive("netem", 0))  # its token went with its session
        agent.close()


def test_a_direct_subscriber_keeps_its_zenoh_threads_python_state() -> None:
    """A handler on Zenoh's own thread runs in one Python thread state from call to call (a
    ``threading.local`` keeps its value) instead of one made and unmade around each sample;
    every sample arrives, in order."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    sender = ZenohBus.open(session_config("peer", None, endpoint))
    receiver = ZenohBus.open(session_config("peer", endpoint, None))
    local = threading.local()
    got: list[tuple[bytes, int, int]] = []  # payload, thread, calls seen by this thread state

    def on(sample: Sample) -> None:
        local.calls = getattr(local, "calls", 0) + 1
        got.append((sample.payload.to_bytes(), threading.get_ident(), local.calls))

    try:
        sub = receiver.declare_subscriber(f"formation/{RUN}/direct", on, direct=True)
        pub = sender.declare_publisher(f"formation/{RUN}/direct")
        while not got:  # until the subscription reached the sender
            pub.put(b"-1")
            time.sleep(0.01)
        for k in range(50):
            pub.put(str(k).encode())
        wait_for(lambda: got[-1][0] == b"49")
        assert [p for p, _, _ in got if p != b"-1"] == [str(k).encode() for k in range(50)]
        calls: dict[int, int] = {}
        for _, thread, seen in got:
            calls[thread] = calls.get(thread, 0) + 1
            assert seen == calls[thread]
        sub.undeclare()
    finally:
        sender.close()
        receiver.close()
