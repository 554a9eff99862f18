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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bench.procfs import thread_cpu_s
from bench.zenoh_message_peer import PAYLOAD
from shell import MEMBER_ENV, MEMBERS_FILE_ENV
from testbed.runtime.processes import ProcessGroup, free_port, wait_for_port

KEY = "bench/message"
TEAM = ["router", "sender", "receiver"]
BUSY_MESSAGES = 1_000  # each may wait for the busy thread's GIL switch interval (5 ms)


@dataclass(frozen=True)
class Way:
    """One way against today's: ``config`` loaded by every process (None: no team QoS rules)."""

    put: str = "publisher"  # bench.zenoh_message_peer.SENDS
    receive: str = "callback"  # bench.zenoh_message_peer.RECEIVES
    config: dict[str, Any] | None = field(default_factory=dict)
    burst: int = 250  # a pool's phase
    busy: bool = False  # a Python thread computing beside the receiver's handler


WAYS: dict[str, Way] = {
    "today (publisher, callback)": Way(),
    "session.put": Way(put="session"),
    "ZBytes payload": Way(put="zbytes"),
    "express": Way(put="express"),
    "congestion DROP": Way(put="drop"),
    "priority DATA_HIGH": Way(put="priority"),
    "encoding set": Way(put="encoding"),
    "callback on Zenoh's thread": Way(receive="direct"),
    "FifoChannel, recv/try_recv": Way(receive="fifo"),
    "RingChannel, recv/try_recv": Way(receive="ring"),
    "ZenohBus, callback": Way(receive="bus"),
    "ZenohBus, on Zenoh's thread": Way(receive="bus_direct"),
    "no team QoS rules": Way(config=None),
    "tx batching off": Way(config={"transport/link/tx/queue/batching/enabled": False}),
    "tx threads 2": Way(config={"transport/link/tx/threads": 2}),
    "QoS priorities off": Way(config={"transport/unicast/qos/enabled": False}),
    "lowlatency": Way(
        config={"transport/unicast/lowlatency": True, "transport/unicast/qos/enabled": False}
    ),
    "router timestamping off": Way(config={"timestamping/enabled": False}),
    "bursts of 1,000 (the leader's)": Way(burst=1000),
    "bursts of 1,000, data queue 16": Way(
        burst=1000, config={"transport/link/tx/queue/size/data": 16}
    ),
}
BUSY: dict[str, Way] = {  # the same handlers while the receiver's main thread computes
    "busy: callback": Way(busy=True),
    "busy: ZenohBus, on Zenoh's thread": Way(receive="bus_direct", busy=True),
    "busy: FifoChannel, recv/try_recv": Way(receive="fifo", busy=True),
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


def _peer(
    role: str, endpoint: str, n: int, way: str, env: dict[str, str], *more: str
) -> subprocess.Popen[str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "bench.zenoh_message_peer", role, endpoint, KEY, str(n), way, *more],
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, **env, MEMBER_ENV: {"send": "sender", "receive": "receiver"}[role]},
    )
    assert proc.stdout is not None
    if proc.stdout.readline().strip() != "ready":
        proc.kill()
        raise RuntimeError(f"the {role} peer did not start")
    return proc


def trial(way: Way, n: int) -> tuple[float, float, float]:
    """CPU µs per message of (the sender, the receiver, the router) for ``way``; the
    receiver's without its busy thread's."""
    config = way.config
    receive = way.receive + ("+busy" if way.busy else "")
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
            peers.append(_peer("receive", endpoint, n, receive, env))
            peers.append(_peer("send", endpoint, n, way.put, env, str(way.burst)))
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


def table(ways: dict[str, Way], n: int, rounds: int) -> None:
    """Each way ``rounds`` times, alternating the order; the first is the baseline."""
    names = list(ways)
    runs: dict[str, list[tuple[float, float, float]]] = {w: [] for w in names}
    for r in range(rounds):
        for name in names if r % 2 == 0 else names[::-1]:
            runs[name].append(trial(ways[name], n))
    med = {w: np.median(np.array(runs[w]), axis=0) for w in names}
    print(f"{f'CPU µs a message, {n} a trial':36} {'put':>6} {'ratio':>6} {'receive':>8} "
          f"{'ratio':>6} {'router':>7} {'ratio':>6}")  # fmt: skip
    for name in names:
        (s, r, q), (s0, r0, q0) = med[name], med[names[0]]
        print(f"{name:36} {s:6.2f} {s / s0:6.2f} {r:8.2f} {r / r0:6.2f} {q:7.2f} {q / q0:6.2f}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--messages", type=int, default=20_000, help="messages a trial")
    p.add_argument("--rounds", type=int, default=3, help="rounds, each every way once")
    p.add_argument("--ways", nargs="*", default=[*WAYS, *BUSY], help="ways to measure")
    args = p.parse_args()
    print(f"{len(PAYLOAD)} B messages with a 24 B attachment, in bursts of 250 but where "
          f"named; {args.rounds} rounds alternating; medians, and ratios to each table's "
          "first row, measured in the same run")  # fmt: skip
    base = next(iter(WAYS))
    ways = {w: WAYS[w] for w in WAYS if w in args.ways or w == base}
    table(ways, args.messages, args.rounds)
    busy = {w: BUSY[w] for w in BUSY if w in args.ways}
    if busy:
        print("with a Python thread computing in the receiver (its own CPU left out):")
        table(busy, BUSY_MESSAGES, args.rounds)
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
