"""An independent Foxglove WebSocket client: the protocol spoken directly with ``websockets``.

Not the SDK: this is what a viewer sees on the wire. The handshake offers the protocol
under both its names (``foxglove.sdk.v1``, which the SDK 0.30 server requires, and
``foxglove.websocket.v1``, the same protocol before the rename). Text frames are JSON
(``serverInfo``, ``advertise``, ``status``); binary frames are opcode ``0x01`` message data
(``uint32`` subscription id, ``uint64`` log time [ns], payload) or ``0x02`` time (``uint64``
[ns]), little-endian.
"""

from __future__ import annotations

import asyncio
import json
import socket
import struct
import time
from dataclasses import dataclass, field
from typing import Any

import websockets
from websockets.asyncio.client import ClientConnection

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 0x01
TIME = 0x02
CONNECT_RETRY_S = 0.05  # between refused connections while the server comes up [s]


@dataclass
class Received:
    """What one client saw."""

    server_info: dict[str, Any] = field(default_factory=dict)
    channels: dict[int, dict[str, Any]] = field(default_factory=dict)  # advertised, by id
    messages: list[tuple[str, int, bytes]] = field(default_factory=list)  # topic, log ns, payload
    times: list[int] = field(default_factory=list)  # broadcast server times [ns]

    def on(self, topic: str) -> list[bytes]:
        return [p for t, _, p in self.messages if t == topic]

    def log_times(self, topic: str) -> list[int]:
        return [ns for t, ns, _ in self.messages if t == topic]


async def connect(url: str, timeout_s: float) -> ClientConnection:
    """Connect once the server accepts (refused connections are retried until ``timeout_s``)."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return await websockets.connect(
                url,
                subprotocols=SUBPROTOCOLS,
                max_size=None,
                ping_interval=None,  # type: ignore[list-item]
            )
        except (OSError, websockets.InvalidHandshake):
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(CONNECT_RETRY_S)


async def idle_subscriber(url: str, channels: dict[int, Any]) -> ClientConnection:
    """Subscribes to every one of ``channels``, then never reads (a tiny receive buffer, one
    queued frame): the stalled viewer the server must not wait for."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # before connect: it sticks
    host, port = url.removeprefix("ws://").split(":")
    sock.connect((host, int(port)))
    ws = await websockets.connect(
        url,
        sock=sock,
        subprotocols=SUBPROTOCOLS,
        max_queue=1,
        ping_interval=None,  # type: ignore[arg-type]
    )
    subs = [{"id": i, "channelId": cid} for i, cid in enumerate(channels)]
    await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
    return ws


async def advertised(ws: ClientConnection, got: Received, topics: set[str]) -> None:
    """Read until ``serverInfo`` and channels for every one of ``topics`` are in."""
    while not (got.server_info and topics <= {c["topic"] for c in got.channels.values()}):
        frame = await ws.recv()
        if isinstance(frame, str):
            on_text(frame, got)


def on_text(frame: str, got: Received) -> None:
    msg = json.loads(frame)
    if msg["op"] == "serverInfo":
        got.server_info = msg
    elif msg["op"] == "advertise":
        for ch in msg["channels"]:
            got.channels[ch["id"]] = ch


async def subscribe(ws: ClientConnection, got: Received, topics: list[str]) -> dict[int, str]:
    """Subscribe to ``topics`` in this order, one message; subscription id → topic."""
    by_topic = {c["topic"]: cid for cid, c in got.channels.items()}
    subs = [{"id": i, "channelId": by_topic[t]} for i, t in enumerate(topics)]
    await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
    return dict(enumerate(topics))


async def read_until(
    ws: ClientConnection, got: Received, subs: dict[int, str], done: Any, timeout_s: float
) -> None:
    """Read frames into ``got`` until ``done(topic, payload)`` is true or the server closes."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            frame = await asyncio.wait_for(ws.recv(), deadline - time.monotonic())
        except websockets.ConnectionClosed:
            return
        if isinstance(frame, str):
            on_text(frame, got)
        elif frame[0] == MESSAGE_DATA:
            sub, log_ns = struct.unpack_from("<IQ", frame, 1)
            topic = subs[sub]
            got.messages.append((topic, log_ns, bytes(frame[13:])))
            if done(topic, frame[13:]):
                return
        elif frame[0] == TIME:
            got.times.append(struct.unpack_from("<Q", frame, 1)[0])


__all__ = [
    "SUBPROTOCOLS",
    "Received",
    "advertised",
    "connect",
    "idle_subscriber",
    "on_text",
    "read_until",
    "subscribe",
]
