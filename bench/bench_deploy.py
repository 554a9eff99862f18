"""Deployment cost: the compose topology (router, client mode, separate hosts, closed network).

Run ``python bench/bench_deploy.py [--epochs E] [--packets P]`` (or ``python -m bench
bench_deploy``). Two measurements, each against a baseline measured in the same run:

1. Lockstep epochs/s of the default scenario (``scenarios/paper.toml``, seed from
   the file, ``--epochs`` overriding its length). Baseline: the plain loopback run
   with every process a zenoh peer on 127.0.0.1. Compared with the launcher in
   client mode through its router (``formation run``'s default), and with ``formation compose``'s
   services run as processes on their own loopback hosts 127.A.B.N
   (:mod:`testkit.loopback`), every service a ``client`` of the router: open, closed
   (user/password + access control) and closed over TLS. The rate is taken from
   the recording (the recorder's receive times of ``leader/estimate``, epochs 2 to
   E − 2), so every case is timed the same way.
2. One-way latency of a coordination packet from a client on 127.A.B.3 through the
   router on 127.A.B.2 to a client on 127.A.B.4: plain TCP (baseline), TCP with
   user/password + access control, and TLS with both; packets 1 ms apart, the
   first 100 left out.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import json
import random
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import zenoh
from mcap.reader import make_reader

from formation import keys
from formation.codec import encode, now_ns
from formation.messages import CoordinationState
from formation.scenario import Scenario
from testbed.deploy import security
from testbed.deploy.compose import ComposeOptions, render
from testbed.runtime.launcher import launch
from testbed.runtime.processes import ProcessGroup, wait_for_port
from testkit.loopback import LoopbackDeployment

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "scenarios" / "paper.toml"
RUN_ID = "bench-deploy"
WARMUP = 100  # latency packets left out [packets]
PROBE = 10**9  # seq of the packets that wait for the route


def estimate_rate(mcap_path: Path, epochs: int) -> float:
    """Epochs/s from the recorder's receive times of the leader's estimates (epochs 2..E-2)."""
    times: dict[int, int] = {}
    with mcap_path.open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
            if channel.topic.endswith("/leader/estimate"):
                times[json.loads(message.data)["epoch"]] = message.log_time
    seen = sorted(k for k in times if 2 <= k <= epochs - 2)
    return (seen[-1] - seen[0]) / ((times[seen[-1]] - times[seen[0]]) / 1e9)


def launcher_rate(scenario: Scenario, runs: Path, mode: str) -> float:
    outcome = launch(scenario, runs_dir=runs, record=True, zenoh_mode=mode)
    return estimate_rate(outcome.run_dir / "run.mcap", scenario.epochs)


def _subnet() -> tuple[int, int]:
    rng = random.SystemRandom()
    return rng.randint(1, 254), rng.randint(1, 254)


def compose_rate(scenario: Scenario, work: Path, options: ComposeOptions) -> float:
    """Epochs/s of ``formation compose``'s services as processes on their own loopback hosts."""
    work.mkdir(parents=True)
    (work / "scenario.toml").write_text(scenario.to_toml())
    compose = work / "compose.yaml"
    compose.write_text(render("scenario.toml", options, scenario))
    a, b = _subnet()
    env = {"FORMATION_RUNS": str(work / "runs"), "RUN_ID": RUN_ID}
    operator = None
    if options.secure:
        hosts = ["router", f"127.{a}.{b}.2"]
        keyset = security.generate(work / "keys", scenario.n, tls=options.tls, tls_hosts=hosts)
        env["FORMATION_KEYS"] = str(keyset.out_dir)
        operator = keyset.config(security.OPERATOR)
    with LoopbackDeployment(compose, work / "logs", env, subnet=(a, b)) as dep:
        workers = [s.name for s in dep.services if s.name not in ("router", "recorder")]
        dep.up(timeout_s=60)
        dep.wait_exit(workers, timeout_s=600)
        endpoint = dep.bound(options.endpoint)
        with zenoh.open(security.client_session_config(endpoint, operator)) as session:
            _flush(session, len(workers))
        dep.down()
    return estimate_rate(work / "runs" / RUN_ID / "run.mcap", scenario.epochs)


def _flush(session: zenoh.Session, statuses: int, timeout_s: float = 30.0) -> None:
    """Wait until the recorder holds every worker's final status (its last message)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for reply in session.get(keys.flush(RUN_ID), timeout=2.0):
            if reply.ok is not None:
                counts = json.loads(reply.ok.payload.to_bytes())
                if sum(1 for k in counts if "/status/" in k and "/recorder/" not in k) >= statuses:
                    return
        time.sleep(0.05)


def one_way_latency_us(work: Path, kind: str, packets: int) -> np.ndarray:
    """Latencies [µs] of coordination packets 127.A.B.3 → router 127.A.B.2 → 127.A.B.4."""
    a, b = _subnet()
    router, src, dst = (f"127.{a}.{b}.{n}" for n in (2, 3, 4))
    tls = kind.startswith("tls")
    endpoint = f"{'tls' if tls else 'tcp'}/{router}:7447"
    group = ProcessGroup(work / f"logs-{kind}")
    pub_conf = sub_conf = None
    args = ["--listen", endpoint]
    env: dict[str, str] = {}
    if kind != "tcp":
        keyset = security.generate(work / f"keys-{kind}", 2, tls=tls, tls_hosts=[router])
        args += ["--passwords", str(keyset.passwords_file)]
        env["ZENOH_CONFIG"] = str(keyset.router_config)
        pub_conf, sub_conf = keyset.config("agent-1"), keyset.config("agent-2")
    try:
        group.start("router", "testbed.runtime.router", *args, env=env)
        wait_for_port(router, 7447, 10.0)
        sub = zenoh.open(security.client_session_config(f"{endpoint}#bind={dst}:0", sub_conf))
        pub = zenoh.open(security.client_session_config(f"{endpoint}#bind={src}:0", pub_conf))
        key = keys.agent_state(RUN_ID, 1)
        sent: dict[int, int] = {}
        got: dict[int, int] = {}
        first = threading.Event()

        def on(sample: zenoh.Sample) -> None:
            got[json.loads(sample.payload.to_bytes())["seq"]] = now_ns()
            first.set()

        subscriber = sub.declare_subscriber(key, on)
        publisher = pub.declare_publisher(
            key, congestion_control=zenoh.CongestionControl.BLOCK, express=True
        )
        deadline = time.monotonic() + 10  # the route is up when a probe arrives
        while not first.wait(0.01) and time.monotonic() < deadline:
            publisher.put(_packet(PROBE))
        for k in range(packets):
            payload = _packet(k)
            sent[k] = now_ns()
            publisher.put(payload)
            time.sleep(0.001)
        deadline = time.monotonic() + 10
        while sum(k < PROBE for k in got) < packets and time.monotonic() < deadline:
            time.sleep(0.01)
        subscriber.undeclare()
        publisher.undeclare()
        pub.close()
        sub.close()
    finally:
        group.stop_all()
    return np.array([got[k] - sent[k] for k in sent if k in got and k >= WARMUP]) / 1e3


def _packet(seq: int) -> bytes:
    msg = CoordinationState(run_id=RUN_ID, sender="agent/1", seq=seq, epoch=seq,
                            stamp_ns=now_ns(), agent=1, position=[0.1, 0.2])  # fmt: skip
    return encode(msg)


def _timed(label: str, fn: Callable[[Path], float], work: Path) -> float:
    start = time.perf_counter()
    value = fn(work)
    print(f"  ({label}: {time.perf_counter() - start:.1f} s)", file=sys.stderr, flush=True)
    return value


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0] if __doc__ else None)
    p.add_argument("--epochs", type=int, default=100, help="lockstep epochs (default 100)")
    p.add_argument("--packets", type=int, default=2000, help="latency packets (default 2000)")
    p.add_argument("--repeat", type=int, default=3, help="runs per case, interleaved (default 3)")
    args = p.parse_args([] if argv is None else argv)
    scenario = Scenario.from_file(SCENARIO).with_overrides(epochs=args.epochs)
    print(f"scenario {SCENARIO.name} (seed {scenario.seed}, {scenario.n} agents, {scenario.epochs} "
          f"epochs, lockstep); best and median of {args.repeat} interleaved runs per case; "
          f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")  # fmt: skip
    with tempfile.TemporaryDirectory(prefix="bench-deploy-") as tmp:
        work = Path(tmp)
        cases: list[tuple[str, Callable[[Path], float]]] = [
            ("plain loopback run (peer, 127.0.0.1) [baseline]",
             lambda d: launcher_rate(scenario, d, "peer")),
            ("launcher through its router (client)", lambda d: launcher_rate(scenario, d, "client")),
            ("compose hosts 127.A.B.N, open",
             lambda d: compose_rate(scenario, d, ComposeOptions(secure=False))),
            ("compose hosts, usrpwd + ACL (the default)",
             lambda d: compose_rate(scenario, d, ComposeOptions())),
            ("compose hosts, usrpwd + ACL over TLS",
             lambda d: compose_rate(scenario, d, ComposeOptions(tls=True))),
        ]  # fmt: skip
        rates: dict[str, list[float]] = {label: [] for label, _ in cases}
        for r in range(args.repeat):
            for c, (label, fn) in enumerate(cases):
                rates[label].append(_timed(label, fn, work / f"lockstep-{c}-{r}"))
        print(f"{'lockstep epochs/s':46} {'best':>7} {'median':>7} {'best ratio':>11}")
        base = max(rates[cases[0][0]])
        for label, values in rates.items():
            best, median = max(values), float(np.median(values))
            print(f"{label:46} {best:7.1f} {median:7.1f} {best / base:11.3f}")
        kinds = (("tcp", "tcp [baseline]"), ("tcp+auth", "tcp, usrpwd + ACL"),
                 ("tls+auth", "tls, usrpwd + ACL"))  # fmt: skip
        runs: dict[str, list[np.ndarray]] = {kind: [] for kind, _ in kinds}
        for r in range(args.repeat):
            for kind, _ in kinds:
                runs[kind].append(one_way_latency_us(work / f"latency-{r}", kind, args.packets))
        print(f"\none-way latency 127.A.B.3 -> router 127.A.B.2 -> 127.A.B.4, {args.packets} packets "
              f"1 ms apart, first {WARMUP} left out; the run with the lowest p50 of {args.repeat} [µs]")  # fmt: skip
        print(f"{'link':24} {'p50':>7} {'p90':>7} {'p99':>7} {'p50 ratio':>10} {'received':>9}")
        base_p50 = None
        for kind, label in kinds:
            lat = min(runs[kind], key=lambda a: float(np.percentile(a, 50)))
            p50, p90, p99 = (float(np.percentile(lat, q)) for q in (50, 90, 99))
            base_p50 = base_p50 or p50
            print(f"{label:24} {p50:7.0f} {p90:7.0f} {p99:7.0f} {p50 / base_p50:10.2f} "
                  f"{len(lat):9d}", flush=True)  # fmt: skip


if __name__ == "__main__":
    main(sys.argv[1:])
