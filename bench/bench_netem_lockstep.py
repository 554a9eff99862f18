"""netem's lockstep core on a pooled team, in one process: CPU ms an epoch of its bundles.

The messages of :mod:`bench.bench_runtime`'s largest case (henneberg_team(1000) in 8 pools,
seed 1, lossless links) are built ahead: each pool's state and report bundle and the leader's
estimates, an epoch's in the order the run sends them. netem runs on the in-memory bus (its
outputs go to a subscriber that keeps their sizes), so only its own CPU is measured: the time
of handling every bundle of an epoch and the loop's flushes. The baseline, in the same run,
takes each bundle's parts one by one (:class:`netem.proxy.bundle_pass.BundlePass` refusing
every bundle); ``--profile`` prints the cProfile of the bundles' path.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time
from typing import Any

import numpy as np
import orjson

from formation import keys
from formation.codec import now_ns
from formation.messages import AgentEstimate, CoordinationState, Measurement, TokenReport
from formation.scenario import Scenario
from netem.node import NetemNode
from netem.proxy.bundle_pass import BundlePass
from shell import MemoryBus, Sample, Service, settle_heap
from testbed.sim.team_generators import henneberg_team

RUN = "bench-netem-lockstep"
SEED = 1
WARM = 4  # epochs before the measured ones
FLUSH_EVERY = 2  # epochs between the loop's flushes (its 0.2 s wake-up at ~10 epochs/s)


def _bundle(sender: str, epoch: int, phase: str, parts: list[tuple[int, str]]) -> bytes:
    head = {"run_id": RUN, "sender": sender, "seq": epoch, "epoch": epoch, "stamp_ns": now_ns()}
    body = [{"agent": i, "seq": epoch, "message": m} for i, m in parts]
    return orjson.dumps({**head, "kind": "bundle", "phase": phase, "parts": body})


def epoch_messages(
    scenario: Scenario, pools: list[list[int]], epoch: int
) -> list[tuple[str, bytes]]:
    """The bundles of ``epoch`` as the run sends them: states, reports, estimates."""
    rng = np.random.default_rng(epoch)
    position = {i: rng.normal(size=2).tolist() for i in range(1, scenario.n + 1)}
    head = {"seq": epoch, "epoch": epoch, "stamp_ns": now_ns()}
    out: list[tuple[str, bytes]] = []
    for ids in pools:
        sender = f"pool/{ids[0]}"
        parts = [
            (
                i,
                CoordinationState(
                    run_id=RUN, sender=sender, **head, agent=i, position=position[i]
                ).model_dump_json(),
            )
            for i in ids
        ]
        out.append((keys.pool_states(RUN, ids[0]), _bundle(sender, epoch, "state", parts)))
    for ids in pools:
        sender = f"pool/{ids[0]}"
        parts = []
        for i in ids:
            z = [
                Measurement(
                    neighbour=j, token=1, z=(np.subtract(position[j], position[i])).tolist()
                )
                for j in scenario.in_neighbours[i - 1]
            ]
            report = TokenReport(run_id=RUN, sender=sender, **head, agent=i, measurements=z)
            parts.append((i, report.model_dump_json()))
        out.append(
            (keys.pool_bundle(RUN, ids[0], "report"), _bundle(sender, epoch, "report", parts))
        )
    parts = []
    for i in range(1, scenario.n + 1):
        near = scenario.in_neighbours[i - 1]
        estimate = AgentEstimate(run_id=RUN, sender="leader", **head, agent=i, neighbours=near,
                                 positions=[position[j] for j in near], v_ref=[0.01, 0.005])  # fmt: skip
        parts.append((i, estimate.model_dump_json()))
    out.append((keys.leader_estimates(RUN), _bundle("leader", epoch, "estimate", parts)))
    return out


class _Rig:
    """netem on the in-memory bus with the team's pools declared; what it sends is counted."""

    def __init__(self, scenario: Scenario, pools: list[list[int]]) -> None:
        bus = MemoryBus()
        self.service = Service(bus, RUN, "netem", 0, start_timeout_s=5)
        self.sent = {"messages": 0, "bytes": 0}
        self.phase_s: dict[str, float] = {}  # CPU [s] by the key's last part (its phase)
        bus.declare_subscriber(f"{keys.ROOT}/{RUN}/**", self._count)
        self.node = NetemNode(self.service, scenario, seed=SEED, wait_for_recorder=False)
        for ids in pools:
            self.node.outbox.declare_pool(ids[0], ids)
        self.node.running = True

    def _count(self, sample: Sample) -> None:
        self.sent["messages"] += 1
        self.sent["bytes"] += len(sample.payload.to_bytes())

    def feed(self, messages: list[tuple[str, Any]]) -> None:
        node, phase_s = self.node, self.phase_s
        for key, payload in messages:
            phase = key.rsplit("/", 1)[-1]
            start = time.process_time()
            with node.lock:
                node.handle_packet(key, payload, None)
            phase_s[phase] = phase_s.get(phase, 0.0) + time.process_time() - start


class _OneByOne(BundlePass):
    """The baseline: every bundle's parts one by one, as if each came alone."""

    def take(self, *_: Any) -> bool:
        return False


def measure(
    scenario: Scenario,
    pools: list[list[int]],
    messages: list[list[tuple[str, bytes]]],
    one_by_one: bool,
    profile: cProfile.Profile | None = None,
) -> tuple[float, dict[str, float], dict[str, int]]:
    """netem's CPU [s] over the epochs after the first :data:`WARM`, the same by phase, and
    what it sent."""
    rig = _Rig(scenario, pools)
    if one_by_one:
        rig.node.bundles = _OneByOne(rig.node.lockstep)
    try:
        for k in range(WARM):
            rig.feed(messages[k])
        rig.node.flush_all()
        settle_heap()  # as netem does at the start
        rig.phase_s.clear()
        start = time.process_time()
        if profile is not None:
            profile.enable()
        for k in range(WARM, scenario.epochs):
            rig.feed(messages[k])
            if k % FLUSH_EVERY == 0:
                rig.node.flush_all()
        rig.node.flush_all()
        if profile is not None:
            profile.disable()
        return time.process_time() - start, rig.phase_s, rig.sent
    finally:
        rig.service.close()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--agents", type=int, default=1000)
    parser.add_argument("--pools", type=int, default=8)
    parser.add_argument("--epochs", type=int, default=40, help="measured, after the warm-up")
    parser.add_argument("--rounds", type=int, default=2, help="baseline and bundles, alternating")
    parser.add_argument("--profile", action="store_true", help="cProfile of the bundles' path")
    args = parser.parse_args(argv)
    scenario = henneberg_team(args.agents, epochs=WARM + args.epochs)
    pools = [list(map(int, a)) for a in np.array_split(np.arange(1, scenario.n + 1), args.pools)]
    messages = [epoch_messages(scenario, pools, k) for k in range(scenario.epochs)]
    print(
        f"seed {SEED}, henneberg_team({args.agents}) in {args.pools} pools, lossless, "
        f"{args.epochs} epochs; netem in one process; CPU ms an epoch; baseline: each bundle's "
        "parts one by one, in the same run"
    )
    cpu: dict[bool, list[float]] = {True: [], False: []}
    for _ in range(args.rounds):
        for one_by_one in (True, False):
            used, phase_s, sent = measure(scenario, pools, messages, one_by_one)
            cpu[one_by_one].append(1e3 * used / args.epochs)
            by_phase = ", ".join(
                f"{p} {1e3 * s / args.epochs:.2f}" for p, s in sorted(phase_s.items())
            )
            print(
                f"  {'one by one' if one_by_one else 'bundles':10} {cpu[one_by_one][-1]:6.2f} "
                f"(by bundle: {by_phase}); {sent['messages'] / scenario.epochs:.1f} messages, "
                f"{sent['bytes'] / scenario.epochs / 1024:.0f} KiB sent an epoch",
                flush=True,
            )
    base, new = min(cpu[True]), min(cpu[False])
    print(
        f"best of {args.rounds}: one by one {base:.2f}, bundles {new:.2f}; ratio {new / base:.2f}"
    )
    if args.profile:
        profile = cProfile.Profile()
        measure(scenario, pools, messages, False, profile)
        pstats.Stats(profile).sort_stats("tottime").print_stats(30)


if __name__ == "__main__":
    main()
