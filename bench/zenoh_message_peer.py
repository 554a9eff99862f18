"""One side of :mod:`bench.bench_zenoh_message`: a Zenoh client that puts or receives N messages.

``python -m bench.zenoh_message_peer send ENDPOINT KEY N WAY [BURST]`` puts ``N`` messages
on ``KEY`` in bursts of ``BURST`` (default :data:`BURST`), once a subscriber matches; ``receive`` takes them by
``WAY`` and returns once ``N`` arrived. Each prints ``ready`` when declared, then one JSON
line: ``{"cpu_s": .., "count": ..}``, the CPU of the whole process (every thread, Zenoh's
too) while it put or received.
"""

from __future__ import annotations

import json
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh

from shell import ZenohBus, session_config

BURST = 250  # a pool's puts in one phase
PAUSE_S = 0.001  # between bursts, as a pool waits for its next phase
TIMEOUT_S = 60.0
# A state message as an agent publishes it, and its codec attachment (epoch, seq, sender).
PAYLOAD = (
    b'{"kind":"state","run_id":"bench","sender":"agent/17","seq":1234,"epoch":1234,'
    b'"stamp_ns":1765000000000000000,"agent":17,"position":[12.3456789012,-3.2109876543]}'
)
ATTACHMENT = bytes(24)

SENDS = ("publisher", "session", "zbytes", "express", "drop", "priority", "encoding")
RECEIVES = ("callback", "direct", "fifo", "ring", "bus", "bus_direct")
CHANNEL = 256  # zenoh's default handler's capacity


def _publisher(session: zenoh.Session, key: str, way: str) -> zenoh.Publisher:
    options: dict[str, Any] = {"congestion_control": zenoh.CongestionControl.BLOCK}
    if way == "express":
        options["express"] = True
    elif way == "drop":
        options["congestion_control"] = zenoh.CongestionControl.DROP
    elif way == "priority":
        options["priority"] = zenoh.Priority.DATA_HIGH
    elif way == "encoding":
        options["encoding"] = zenoh.Encoding.APPLICATION_JSON
    return session.declare_publisher(key, **options)


def send(session: zenoh.Session, key: str, n: int, way: str, burst: int) -> dict[str, float]:
    pub = _publisher(session, key, way)
    deadline = time.monotonic() + TIMEOUT_S
    while not pub.matching_status.matching:  # the receiver's subscription reached us
        if time.monotonic() > deadline:
            raise RuntimeError("no subscriber matched")
        time.sleep(0.01)
    print("ready", flush=True)
    put: Callable[[bytes], Any]
    if way == "session":
        block = zenoh.CongestionControl.BLOCK

        def put(payload: bytes) -> None:
            session.put(key, payload, attachment=ATTACHMENT, congestion_control=block)
    elif way == "zbytes":

        def put(payload: bytes) -> None:
            pub.put(zenoh.ZBytes(payload), attachment=zenoh.ZBytes(ATTACHMENT))
    else:

        def put(payload: bytes) -> None:
            pub.put(payload, attachment=ATTACHMENT)

    cpu0 = time.process_time()
    for k in range(n):
        put(PAYLOAD + b" " * (k % 2))  # a fresh bytes object each time, as the services build
        if k % burst == burst - 1:
            time.sleep(PAUSE_S)
    cpu = time.process_time() - cpu0
    pub.undeclare()
    return {"cpu_s": cpu, "count": n}


def receive(session: zenoh.Session, key: str, n: int, way: str) -> dict[str, float]:
    """``way`` ending in ``+busy``: a thread computes in Python meanwhile, its CPU left out."""
    way, _, busy = way.partition("+")
    got = {"count": 0, "cpu0": 0.0, "cpu1": 0.0, "busy0": 0.0, "busy1": 0.0}
    done = threading.Event()

    def compute() -> None:  # holds the GIL but for the interpreter's switches
        while not got["count"]:
            sum(range(200))
        got["busy0"] = time.thread_time()
        while not done.is_set():
            sum(range(200))
        got["busy1"] = time.thread_time()

    computing = threading.Thread(target=compute, daemon=True)
    if busy:
        computing.start()

    def handle(sample: zenoh.Sample) -> None:
        # what shell.service's inbox takes of every sample
        str(sample.key_expr)
        sample.payload.to_bytes()
        att = sample.attachment
        if att is not None:
            att.to_bytes()
        got["count"] += 1
        if got["count"] == 1:
            got["cpu0"] = time.process_time()
        elif got["count"] >= n:
            got["cpu1"] = time.process_time()
            done.set()

    if way in ("bus", "bus_direct"):  # the product's way: shell.ZenohBus
        sub = ZenohBus(session).declare_subscriber(key, handle, direct=way == "bus_direct")
        print("ready", flush=True)
        if not done.wait(TIMEOUT_S):
            raise RuntimeError(f"{got['count']} of {n} samples in {TIMEOUT_S:g} s")
    elif way in ("callback", "direct"):
        handler: Any = zenoh.handlers.Callback(handle, indirect=way == "callback")
        sub = session.declare_subscriber(key, handler)
        print("ready", flush=True)
        if not done.wait(TIMEOUT_S):
            raise RuntimeError(f"{got['count']} of {n} samples in {TIMEOUT_S:g} s")
    else:
        channel: Any = (
            zenoh.handlers.FifoChannel(CHANNEL)
            if way == "fifo"
            else zenoh.handlers.RingChannel(n)  # no loss in the bench, whatever its pace
        )
        sub = session.declare_subscriber(key, channel)
        print("ready", flush=True)
        while got["count"] < n:  # block for the first of a burst, then take what is there
            handle(sub.recv())
            while got["count"] < n and (sample := sub.try_recv()) is not None:
                handle(sample)
    done.set()
    if busy:
        computing.join()
    sub.undeclare()
    cpu = got["cpu1"] - got["cpu0"] - (got["busy1"] - got["busy0"])
    return {"cpu_s": cpu, "count": got["count"] - 1}


def main(argv: list[str]) -> int:
    role, endpoint, key, n, way = argv[0], argv[1], argv[2], int(argv[3]), argv[4]
    burst = int(argv[5]) if argv[5:] else BURST
    with zenoh.open(session_config("client", endpoint)) as session:
        if role == "send":
            result = send(session, key, n, way, burst)
        else:
            result = receive(session, key, n, way)
    print(json.dumps(result), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
