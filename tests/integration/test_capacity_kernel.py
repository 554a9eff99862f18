"""Our capacity queue against Linux's ``tbf``: the same UDP datagrams, the same counts.

The test makes a network namespace of its own (root), puts ``tbf`` on its loopback, and
sends a pattern of datagrams to a socket in it (bursts over the limit, a refill, a packet
larger than the bucket, a stream at twice the rate). The kernel's delivered and dropped
counts (``tc -s qdisc``) and the bytes it sent must equal what ``netem.links.capacity``
gives for the same send times and sizes; a packet on loopback is its payload plus 42 bytes
(Ethernet 14, IPv4 20, UDP 8). The plan is checked first to be robust: jittering its send
times by ±4 ms does not change the model's counts, so scheduling noise cannot decide it.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest

from netem.links.capacity import OVERSIZE, QUEUE_FULL, QueueParams, serve_queue

RATE_BPS = 80_000  # [bit/s] 10,000 B/s: a 1,000-byte packet every 0.1 s
BURST = 3000  # [B]
LIMIT = 5000  # [B] tbf's limit: bytes waiting
OVERHEAD = 42  # [B] Ethernet + IPv4 + UDP headers on loopback
PAYLOAD = 1000 - OVERHEAD


def plan() -> tuple[np.ndarray, np.ndarray]:
    """Send times [s] from the start and payload sizes [B]."""
    times: list[float] = []
    sizes: list[int] = []
    times += [0.0] * 20  # over the credit and the limit: 3 + 5 pass
    times += [0.65] * 8  # the bucket refilled 1,500 B since the queue drained at 0.5
    times += [1.5]  # larger than the bucket: tbf drops it
    # Poisson at 2.9 times the rate on a full bucket (a periodic stream would tie its arrivals
    # to the 0.1 s grid the queue leaves on; this seed's stream keeps 4 ms from every edge)
    times += (1.6 + np.cumsum(np.random.default_rng(5).exponential(0.035, 24))).tolist()
    sizes = [PAYLOAD] * 28 + [4000 - OVERHEAD] + [PAYLOAD] * 24
    return np.array(times), np.array(sizes)


SENDER = r"""
import json, socket, subprocess, sys, time
plan = json.loads(sys.argv[1])
rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
rx.bind(("127.0.0.1", 0))
tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
dest = rx.getsockname()
sent = []
start = time.monotonic()
for k, (at, size) in enumerate(zip(plan["times"], plan["sizes"])):
    while time.monotonic() - start < at:
        time.sleep(min(0.002, max(0.0, at - (time.monotonic() - start))))
    payload = k.to_bytes(4, "big") + bytes(size - 4)
    sent.append(time.monotonic() - start)
    tx.sendto(payload, dest)
# ready when the qdisc holds nothing more: then every datagram it passed is in the socket
deadline = time.monotonic() + 30.0
while time.monotonic() < deadline:
    out = subprocess.run(["tc", "-s", "qdisc", "show", "dev", "lo"], capture_output=True, text=True).stdout
    if "backlog 0b 0p" in out:
        break
    time.sleep(0.02)
rx.settimeout(1.0)
got = []
try:
    while True:
        got.append(int.from_bytes(rx.recv(65536)[:4], "big"))
        rx.settimeout(0.2)
except socket.timeout:
    pass
print(json.dumps({"sent": sent, "got": got}))
"""


def _run(*argv: str, check: bool = True) -> subprocess.CompletedProcess[str]:
    return subprocess.run(argv, capture_output=True, text=True, check=check, timeout=60)


@pytest.fixture
def namespace() -> object:
    if shutil.which("ip") is None or shutil.which("tc") is None:
        pytest.skip("iproute2 (ip, tc) is not installed")
    if os.geteuid() != 0:
        pytest.skip("making a network namespace needs root")
    name = f"fcap{os.getpid()}"
    made = _run("ip", "netns", "add", name, check=False)
    if made.returncode != 0:
        pytest.skip(f"cannot make a network namespace here: {made.stderr.strip()}")
    try:
        _run("ip", "netns", "exec", name, "ip", "link", "set", "lo", "up")
        tbf = _run(
            "ip",
            "netns",
            "exec",
            name,
            "tc",
            "qdisc",
            "add",
            "dev",
            "lo",
            "root",
            "tbf",
            "rate",
            f"{RATE_BPS}bit",
            "burst",
            str(BURST),
            "limit",
            str(LIMIT),
            check=False,
        )
        if tbf.returncode != 0:
            pytest.skip(f"the kernel has no tbf qdisc: {tbf.stderr.strip()}")
        yield name
    finally:
        _run("ip", "netns", "del", name, check=False)


def test_the_plan_is_robust_to_scheduling_jitter() -> None:
    times, sizes = plan()
    params = QueueParams(
        rate_bps=RATE_BPS, burst_bytes=BURST, limit_bytes=LIMIT, overhead_bytes=OVERHEAD
    )
    exact = serve_queue(params, times, sizes).reason
    rng = np.random.default_rng(29)
    for _ in range(200):
        jittered = np.maximum.accumulate(times + rng.uniform(-0.004, 0.004, times.size))
        assert np.array_equal(serve_queue(params, jittered, sizes).reason, exact)
    # the pattern exercises every way tbf treats a packet
    assert (exact == QUEUE_FULL).sum() == 12 + 2 + 10 and (exact == OVERSIZE).sum() == 1


@pytest.mark.slow
def test_tbf_on_loopback_delivers_and_drops_what_the_model_says(namespace: str) -> None:
    times, sizes = plan()
    out = _run(
        "ip",
        "netns",
        "exec",
        namespace,
        sys.executable,
        "-c",
        SENDER,
        json.dumps({"times": times.tolist(), "sizes": sizes.tolist()}),
    )
    result = json.loads(out.stdout)
    stats = _run("ip", "netns", "exec", namespace, "tc", "-s", "qdisc", "show", "dev", "lo").stdout
    sent_bytes, sent_pkts, dropped = map(
        int,
        re.search(r"Sent (\d+) bytes (\d+) pkt \(dropped (\d+)", stats).groups(),  # type: ignore[union-attr]
    )
    params = QueueParams(
        rate_bps=RATE_BPS, burst_bytes=BURST, limit_bytes=LIMIT, overhead_bytes=OVERHEAD
    )
    model = serve_queue(params, np.array(result["sent"]), sizes)
    assert sent_pkts == int(model.passed.sum()) == len(result["got"]), stats
    assert dropped == int((~model.passed).sum()), stats
    assert sorted(result["got"]) == model.passed.nonzero()[0].tolist()  # the same packets
    assert sent_bytes == int(model.size_bytes[model.passed].sum())  # sizes: payload + 42
