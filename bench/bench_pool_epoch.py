"""A pool process's own work of an epoch, replayed from a recorded run: CPU per epoch.

Run ``python -m bench.bench_pool_epoch [--epochs E] [--repeats R]``. Records a lockstep run of
``henneberg_team(1000)`` pooled in 8 processes (seed 1), then feeds the first pool's recorded
batches (``inbox/pool/1/state`` and ``estimate``) to an agent node of that pool on an in-memory
bus, epoch by epoch, as Zenoh's thread would: decoding the batches, stepping 125 agents,
making their states and reports and the bundles. What it publishes must equal what the pool
published in the run (stamps aside), so the replay is the run's work to the bit. Printed: the
best CPU ms per epoch of ``--repeats`` replays and the time of each part; baseline, measured in
the same run: the in-process simulator's CPU per epoch for the whole team (all 1,000 agents).
"""

from __future__ import annotations

import os

os.environ["OPENBLAS_NUM_THREADS"] = "1"  # before numpy: one core, comparable numbers

import argparse
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import orjson
from mcap.reader import make_reader

import agent.node
from agent.node import AgentNode
from agent.runner import AgentRunner
from formation import keys
from formation.scenario import Scenario
from shell import Incoming, Lockstep, MemoryBus, Service, settle_heap
from shell.inbox import LockstepInbox
from testbed.runtime.launcher import launch
from testbed.sim.simulate import simulate
from testbed.sim.team_generators import henneberg_team

SEED = 1
POOL = 1  # the first pool: agents 1..125
Recording = tuple[Scenario, str, list[tuple[str, bytes]], dict[str, list[bytes]]]


def record(epochs: int, runs: Path) -> Recording:
    """(scenario, run id, pool 1's batches in epoch and phase order, what it published by key)."""
    outcome = launch(henneberg_team(1000, epochs=epochs), seed=SEED, runs_dir=runs, pool=8)
    run = outcome.run_id
    inbound = {keys.inbox_pool(run, POOL, p) for p in ("state", "estimate")}
    outbound = {keys.pool_states(run, POOL), keys.pool_bundle(run, POOL, "report")}
    batches: list[tuple[str, bytes]] = []
    published: dict[str, list[bytes]] = {}
    with (outcome.run_dir / "run.mcap").open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages(topics=[*inbound, *outbound]):
            if channel.topic in inbound:
                batches.append((channel.topic, message.data))
            else:
                published.setdefault(channel.topic, []).append(message.data)
    batches.sort(key=lambda b: (orjson.loads(b[1])["epoch"], b[0].endswith("estimate")))
    scenario = Scenario.from_file(outcome.run_dir / "scenario.toml")
    return scenario, run, batches, published


def _unstamped(payload: bytes) -> Any:
    bundle = orjson.loads(payload)
    del bundle["stamp_ns"]
    for part in bundle["parts"]:
        part["message"] = {
            k: v for k, v in orjson.loads(part["message"]).items() if k != "stamp_ns"
        }
    return bundle


def replay(recording: Recording, check: bool = False) -> float:
    """Feed the batches to a fresh node of pool 1; its CPU seconds. ``check``: what it
    publishes equals the recording's."""
    scenario, run, batches, published = recording
    bus = MemoryBus()
    service = Service(bus, run, "pool", POOL)
    got: dict[str, list[bytes]] = {}
    for key in published:
        bus.declare_subscriber(key, lambda s, k=key: got.setdefault(k, []).append(s.payload.to_bytes()))  # type: ignore[misc]  # fmt: skip
    ids = list(range(POOL, POOL + 125))
    node = AgentNode(service, scenario, ids, scenario.strategy.name, seed=SEED)
    node.bundled = True  # as netem took the pool's declaration
    inbox = LockstepInbox(service, ids, node.deadline)
    loop = node._epochs(Lockstep(), inbox)
    waiting: list[Any] = []

    def advance() -> None:  # as Lockstep.drive advances the loop on Zenoh's thread
        try:
            while not waiting or waiting[0].complete():
                waiting[:] = [loop.send(False) if waiting else next(loop)]
        except StopIteration:
            pass

    start = time.process_time()
    advance()
    for key, data in batches:
        inbox.route(Incoming(key, data, None))
        advance()
    spent = time.process_time() - start
    if check:
        for key, sent in published.items():
            if [_unstamped(p) for p in got.get(key, [])] != [_unstamped(p) for p in sent]:
                raise SystemExit(f"the replay published on {key} other than the run")
        if service.malformed.counts:
            raise SystemExit(f"the replay counted malformed messages: {service.malformed.counts}")
    return spent


PARTS: list[tuple[Any, str, str]] = [
    (LockstepInbox, "route", "batch decoded and filed"),
    (LockstepInbox, "_columns", "packets decoded into columns"),
    (agent.node, "delivered_states", "states as arrays"),
    (AgentRunner, "receive", "runner: receive"),
    (AgentNode, "_publish_reports", "reports and their bundle"),
    (agent.node, "delivered_estimates", "estimates as arrays"),
    (AgentRunner, "step", "runner: step"),
    (AgentNode, "_publish_states", "states and their bundle"),
]


def _timed(parts: Counter[str]) -> list[Callable[[], None]]:
    """Wrap each part to add its thread CPU to ``parts``; returns the undo of each wrap."""
    undo = []
    for owner, name, label in PARTS:
        original = getattr(owner, name)

        def timed(*args: Any, _f: Any = original, _label: str = label, **kw: Any) -> Any:
            t0 = time.thread_time()
            try:
                return _f(*args, **kw)
            finally:
                parts[_label] += time.thread_time() - t0

        setattr(owner, name, timed)
        undo.append(lambda o=owner, n=name, f=original: setattr(o, n, f))
    return undo


def simulator_cpu_s(scenario: Scenario) -> float:
    """The simulator's CPU per epoch for the whole team, setup left out (two lengths)."""
    spent = []
    for epochs in (scenario.epochs, 3 * scenario.epochs):
        t0 = time.process_time()
        simulate(scenario.with_overrides(epochs=epochs), seed=SEED)
        spent.append(time.process_time() - t0)
    return (spent[1] - spent[0]) / (2 * scenario.epochs)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--epochs", type=int, default=30, help="epochs of the recorded run")
    parser.add_argument("--repeats", type=int, default=7, help="replays; the best is shown")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        recording = record(args.epochs, Path(tmp))
    scenario = recording[0]
    replay(recording, check=True)
    settle_heap()  # as a service does once its run starts
    best, parts = float("inf"), Counter[str]()
    for _ in range(args.repeats):
        spent: Counter[str] = Counter()
        undo = _timed(spent)
        cpu_s = replay(recording)
        for f in undo:
            f()
        if cpu_s < best:
            best, parts = cpu_s, spent
    per_epoch_ms = 1e3 * best / scenario.epochs
    sim_ms = 1e3 * simulator_cpu_s(scenario)
    print(f"seed {SEED}; {scenario.n} agents, pool of 125 (agents 1-125), {scenario.epochs} epochs "
          f"replayed from a recorded lockstep run (load {os.getloadavg()[0]:.1f})")  # fmt: skip
    print(f"pool epoch CPU {per_epoch_ms:.2f} ms (best of {args.repeats}, parts timed); "
          f"baseline: simulator epoch of all {scenario.n} agents {sim_ms:.2f} ms; "
          f"ratio {per_epoch_ms / sim_ms:.2f}")  # fmt: skip
    for label, s in parts.most_common():
        print(f"  {label:32} {1e3 * s / scenario.epochs:6.3f} ms")


if __name__ == "__main__":
    main()
