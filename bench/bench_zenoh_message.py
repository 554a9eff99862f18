"""What one Zenoh message costs in CPU: each way to put and to receive, against today's way.

Three processes on 127.0.0.1, as in ``formation run``: our router, a client that puts
``N`` state-sized messages on one key in bursts of 250 (a pool's phase), a client that
receives them. Each way changes one thing against today's (a declared publisher that
blocks, bytes, a Python callback on its own thread, the team's QoS rules, zenoh's
default transport): the put, the received sample's handler, or the config every
process loads (``ZENOH_CONFIG``). Rounds alternate the order; medians of the CPU µs per
message of each process (every thread), and their ratios to today's in the same run.
No randomness (no seed).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from bench.procfs import thread_cpu_s
from bench.zenoh_message_peer import PAYLOAD
from shell import MEMBER_ENV, MEMBERS_FILE_ENV
from testbed.runtime.processes import ProcessGroup, free_port, wait_for_port

KEY = "bench/message"
TEAM = ["router", "sender", "receiver"]

# name: (config loaded by every process or None for no team rules, put way, receive way)
WAYS: dict[str, tuple[dict[str, Any] | None, str, str]] = {
    "today (publisher, callback)": ({}, "publisher", "callback"),
    "session.put": ({}, "session", "callback"),
    "ZBytes payload": ({}, "zbytes", "callback"),
    "express": ({}, "express", "callback"),
    "congestion DROP": ({}, "drop", "callback"),
    "priority DATA_HIGH": ({}, "priority", "callback"),
    "encoding set": ({}, "encoding", "callback"),
    "callback on Zenoh's thread": ({}, "publisher", "direct"),
    "FifoChannel, recv/try_recv": ({}, "publisher", "fifo"),
    "RingChannel, recv/try_recv": ({}, "publisher", "ring"),
    "ZenohBus, callback": ({}, "publisher", "bus"),
    "ZenohBus, on Zenoh's thread": ({}, "publisher", "bus_direct"),
    "no team QoS rules": (None, "publisher", "callback"),
    "tx batching off": (
        {"transport/link/tx/queue/batching/enabled": False},
        "publisher",
        "callback",
    ),
    "tx threads 2": ({"transport/link/tx/threads": 2}, "publisher", "callback"),
    "QoS priorities off": ({"transport/unicast/qos/enabled": False}, "publisher", "callback"),
    "lowlatency": (
        {"transport/unicast/lowlatency": True, "transport/unicast/qos/enabled": False},
        "publisher",
        "callback",
    ),
}


def _config_file(tmp: Path, config: dict[str, Any]) -> Path:
    """A JSON5 config of ``config``'s paths (``a/b/c``) nested, for ``ZENOH_CONFIG``."""
    tree: dict[str, Any] = {}
    for path, value in config.items():
        *parents, leaf = path.split("/")
        node = tree
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    path = tmp / "zenoh.json5"
    path.write_text(json.dumps(tree))
    return path


def _peer(role: str, endpoint: str, n: int, way: str, env: dict[str, str]) -> subprocess.Popen[str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "bench.zenoh_message_peer", role, endpoint, KEY, str(n), way],
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, **env, MEMBER_ENV: {"send": "sender", "receive": "receiver"}[role]},
    )
    assert proc.stdout is not None
    if proc.stdout.readline().strip() != "ready":
        proc.kill()
        raise RuntimeError(f"the {role} peer did not start")
    return proc


def trial(way: str, n: int) -> tuple[float, float, float]:
    """CPU µs per message of (the sender, the receiver, the router) for ``way``."""
    config, send_way, receive_way = WAYS[way]
    with tempfile.TemporaryDirectory() as tmp:
        env = {"ZENOH_CONFIG": str(_config_file(Path(tmp), config or {}))}
        members = None
        if config is not None:
            members = Path(tmp) / "members.json"
            members.write_text(json.dumps(TEAM))
            env[MEMBERS_FILE_ENV] = str(members)
        port = free_port()
        endpoint = f"tcp/127.0.0.1:{port}"
        group = ProcessGroup(Path(tmp) / "logs", members_file=members)
        peers: list[subprocess.Popen[str]] = []
        try:
            router = group.start("router", "testbed.runtime.router", "--listen", endpoint, env=env)
            wait_for_port("127.0.0.1", port, 10)
            peers.append(_peer("receive", endpoint, n, receive_way, env))
            peers.append(_peer("send", endpoint, n, send_way, env))
            router0 = thread_cpu_s(router.pid)
            sent = json.loads(peers[1].communicate(timeout=120)[0].strip().splitlines()[-1])
            got = json.loads(peers[0].communicate(timeout=120)[0].strip().splitlines()[-1])
            router_cpu = thread_cpu_s(router.pid) - router0
        finally:
            for proc in peers:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
            group.stop_all()
    return (1e6 * sent["cpu_s"] / n, 1e6 * got["cpu_s"] / got["count"], 1e6 * router_cpu / n)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--messages", type=int, default=20_000, help="messages a trial")
    p.add_argument("--rounds", type=int, default=3, help="rounds, each every way once")
    p.add_argument("--ways", nargs="*", default=list(WAYS), help="ways to measure")
    args = p.parse_args()
    ways = [w for w in WAYS if w in args.ways]
    base = next(iter(WAYS))
    if base not in ways:
        ways.insert(0, base)
    print(f"{args.messages} messages of {len(PAYLOAD)} B a trial, bursts of 250; "
          f"{args.rounds} rounds alternating; baseline: {base}, in the same run")  # fmt: skip
    runs: dict[str, list[tuple[float, float, float]]] = {w: [] for w in ways}
    for r in range(args.rounds):
        for way in ways if r % 2 == 0 else ways[::-1]:
            runs[way].append(trial(way, args.messages))
    med = {w: np.median(np.array(runs[w]), axis=0) for w in ways}
    print(f"{'CPU µs a message (median)':32} {'put':>6} {'ratio':>6} {'receive':>8} {'ratio':>6} "
          f"{'router':>7} {'ratio':>6}")  # fmt: skip
    for way in ways:
        (s, r, q), (s0, r0, q0) = med[way], med[base]
        print(f"{way:32} {s:6.2f} {s / s0:6.2f} {r:8.2f} {r / r0:6.2f} {q:7.2f} {q / q0:6.2f}")
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
