"""A client started before its router connects once the router listens (real Zenoh, 127.0.0.1)."""

from __future__ import annotations

import argparse
import socket
import threading
import time
from typing import Any

import pytest
import zenoh

from formation.errors import RuntimeFailure
from shell.zenoh_config import open_session, session_config

pytestmark = pytest.mark.integration


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def client_args(port: int, timeout_s: float) -> argparse.Namespace:
    return argparse.Namespace(
        mode="client", connect=f"tcp/127.0.0.1:{port}", listen=None, connect_timeout=timeout_s
    )


def test_client_waits_for_a_router_that_starts_later() -> None:
    port = free_port()
    opened: list[Any] = []
    errors: list[BaseException] = []

    def connect() -> None:
        try:
            opened.append(open_session(client_args(port, 30.0)))
        except BaseException as exc:
            errors.append(exc)

    client = threading.Thread(target=connect)
    client.start()
    time.sleep(1.5)  # the point of the test: the router is late
    assert client.is_alive() and not opened
    router = zenoh.open(session_config("router", None, f"tcp/127.0.0.1:{port}"))
    try:
        client.join(20)
        assert not errors and len(opened) == 1
        received = threading.Event()
        sub = router.declare_subscriber("retry/probe", lambda s: received.set())
        deadline = time.monotonic() + 10
        while not received.is_set() and time.monotonic() < deadline:
            opened[0].put("retry/probe", b"1")
            received.wait(0.1)
        sub.undeclare()
        assert received.is_set()
    finally:
        for s in opened:
            s.close()
        router.close()


def test_no_router_is_a_clear_error_after_the_bound() -> None:
    port = free_port()
    t0 = time.monotonic()
    with pytest.raises(
        RuntimeFailure,
        match=rf"cannot open a Zenoh session \(tcp/127\.0\.0\.1:{port}\) within 1 s \(\d+ attempts\)",
    ):
        open_session(client_args(port, 1.0))
    assert 0.9 < time.monotonic() - t0 < 5
