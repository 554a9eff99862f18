"""ZenohBus does what MemoryBus does (tests/unit/shell/test_bus.py), between two real peers
on 127.0.0.1: samples by key expression, queries, liveliness tokens with history."""

from __future__ import annotations

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
