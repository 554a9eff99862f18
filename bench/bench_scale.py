"""Teams of ten thousand (issue 27): every stage at 1,000 and 10,000 agents, in one run.

Seed 1 throughout; teams from ``testbed.sim.team_generators.rigid_team`` (perturbed grid,
vertex addition, ``redundancy`` spare edges), 10 % Bernoulli loss on every formation link,
the tree estimator, ``hold``. The rigidity rows and ``formation simulate`` also on
``henneberg_team`` and ``geometric_team``, 10 % and 50 % spare edges, in bursts of loss
too, each against the paths as they were (``Before``: growth in rounds of numpy, its
candidates all by SVD, forests by a Python union-find, keyed draws and loss chains in
numpy), the two alternating. Baselines measured in the same run: the load of the 2-D minimally
rigid team; the simulator at 100 agents; the batched sweep at 100 agents.

    python -m bench.bench_scale [--quick] [--rigidity-only | --simulate-only | --exact-only]
                                [--team henneberg-2]

``--simulate-only --team rigid_team-3``: the 3-D ``rigid_team`` rows of ``formation simulate``.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from collections.abc import Callable
from typing import Any

import numpy as np

import agent.control
import agent.measurement
import leader.mst
import leader.rigidity
import leader.tree
from formation import keyed_random, rigidity_check, rigidity_growth
from formation.rigidity import expected_rigidity_rank, rigidity_rank
from formation.rigidity_check import rank_under_mask
from formation.rigidity_growth import growth_rounds, spans_without_any
from formation.rigidity_stiffness import pinned_stiffness_definite
from formation.scenario import Scenario
from leader import HealthyRigidity, Leader
from netem.links import chains
from netem.links.linkmodels import gilbert_elliott
from recorder import load_run, write_report, write_report_from
from recorder.live.scene import scene_update
from testbed.sim.batch import run_batch
from testbed.sim.plan import plan_batch
from testbed.sim.simulate import simulate
from testbed.sim.team_generators import geometric_team, henneberg_team, rigid_team
from testkit.synthetic import write_synthetic

ROOT = Path(__file__).resolve().parents[1]
SEED = 1
LOSS = {"formation_default": [{"model": "bernoulli", "p_loss": 0.1}]}
LOAD = """
import resource, sys, time
from formation.scenario import Scenario
from recorder import load_run, write_report, write_report_from
from recorder.live.scene import scene_update
from testkit.synthetic import write_synthetic
t = time.perf_counter(); Scenario.from_file(sys.argv[1]); dt = time.perf_counter() - t
print(dt, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
"""


def team(n: int, d: int = 2, redundancy: float = 0.1, epochs: int = 100) -> Scenario:
    return rigid_team(
        n, d, redundancy, seed=SEED, epochs=epochs, network=LOSS, strategy={"name": "hold"}
    )


def load_times(tmp: Path) -> None:
    print("load and validate a scenario file, 10,000 agents (a fresh process each; peak RSS of it)")
    print(f"{'team':28} {'edges':>7} {'load s':>7} {'peak MB':>8} {'ratio':>6}")
    base = None
    for d in (2, 3):
        for redundancy in (0.0, 0.1):
            path = tmp / f"team{d}{redundancy}.toml"
            path.write_text(team(10_000, d, redundancy).to_toml())
            out = subprocess.run(
                [sys.executable, "-c", LOAD, str(path)], capture_output=True, text=True, check=True
            )
            seconds, peak = map(float, out.stdout.split())
            base = base or seconds
            edges = len(Scenario.from_file(path).edges)
            print(
                f"{f'{d}-D, redundancy {redundancy:g}':28} {edges:7d} {seconds:7.2f} {peak:8.0f} {seconds / base:6.2f}",
                flush=True,
            )


def healthy_masks(s: Scenario, epochs: int) -> np.ndarray:
    """The leader's healthy edges under the scenario's loss, ``either`` rule: (epochs, m)."""
    plan = plan_batch(s, [SEED], epochs=epochs)
    return np.asarray(plan.on_time[:, 0]).reshape(epochs, -1, 2).any(axis=2)


FAMILIES = {"henneberg": henneberg_team, "rigid_team": rigid_team, "geometric": geometric_team}
BURSTY = {"formation_default": [{"model": "gilbert_elliott", "p": 1 / 30, "r": 0.3}]}
"""Bursts of 3.3 epochs on average, 10 % of epochs lost: the Bernoulli rows' mean loss."""


def family_team(
    family: str, d: int, redundancy: float, epochs: int, network: dict[str, Any] = LOSS
) -> Scenario:
    """A 10,000-agent team of a family (Henneberg only in the plane), seed 1."""
    fields = {"epochs": epochs, "network": network, "strategy": {"name": "hold"}}
    if family == "henneberg":
        return henneberg_team(10_000, seed=SEED, redundancy=redundancy, **fields)
    return FAMILIES[family](10_000, d, redundancy, seed=SEED, **fields)


ONLY: list[str] = []
"""``--team``: the rows of these teams (``family-d``) only; empty: every team."""


def teams() -> list[tuple[str, int]]:
    every = [(f, d) for f in FAMILIES for d in ((2,) if f == "henneberg" else (2, 3))]
    return [(f, d) for f, d in every if not ONLY or f"{f}-{d}" in ONLY]


class Before:
    """The paths as they were: growth in rounds of numpy, every candidate's directions by
    SVD, half-edges sorted by 64-bit keys, the forests by a Python union-find, every covariance inverted,
    sums per group and per agent by ``np.add.at``, the fused pairs by ``np.unique``, keyed
    draws and loss chains in numpy, the noise over every factor. Entered, it puts them
    back; left, it restores today's."""

    def __enter__(self) -> None:
        self.saved = (
            rigidity_growth.growth_rounds,
            rigidity_check.growth_rounds,
            leader.rigidity.growth_rounds,
            rigidity_growth._surely_spanning,
            rigidity_growth._half_edges,
            leader.mst._sparse_scan,
            leader.mst.UNION_FIND_FROM,
            leader.tree._inverses,
            leader.tree._group_sums,
            leader.tree.pair_groups,
            agent.control._per_agent,
            agent.measurement._correlate,
            keyed_random.COMPILED_FROM,
            chains.COMPILED_FROM,
            gilbert_elliott.COMPILED_FROM,
        )
        rigidity_growth.growth_rounds = rigidity_growth.reference_growth_rounds
        rigidity_check.growth_rounds = rigidity_growth.reference_growth_rounds
        leader.rigidity.growth_rounds = rigidity_growth.reference_growth_rounds
        rigidity_growth._surely_spanning = _never_sure
        rigidity_growth._half_edges = _half_edges_by_int64
        leader.mst._sparse_scan = _union_find_forests
        leader.mst.UNION_FIND_FROM = NEVER
        leader.tree._inverses = np.linalg.inv
        leader.tree._group_sums = _group_sums_by_add_at
        leader.tree.pair_groups = _pair_groups_by_unique
        agent.control._per_agent = _per_agent_by_add_at
        agent.measurement._correlate = _correlate_every_factor
        keyed_random.COMPILED_FROM = chains.COMPILED_FROM = NEVER
        gilbert_elliott.COMPILED_FROM = NEVER

    def __exit__(self, *exc: object) -> None:
        (
            rigidity_growth.growth_rounds,
            rigidity_check.growth_rounds,
            leader.rigidity.growth_rounds,
            rigidity_growth._surely_spanning,
            rigidity_growth._half_edges,
            leader.mst._sparse_scan,
            leader.mst.UNION_FIND_FROM,
            leader.tree._inverses,
            leader.tree._group_sums,
            leader.tree.pair_groups,
            agent.control._per_agent,
            agent.measurement._correlate,
            keyed_random.COMPILED_FROM,
            chains.COMPILED_FROM,
            gilbert_elliott.COMPILED_FROM,
        ) = self.saved


NEVER = 1 << 62  # a size no draw, chain or batch reaches: the compiled paths left out


def _pair_groups_by_unique(pair: np.ndarray) -> tuple[np.ndarray, ...]:
    return tuple(np.unique(pair, return_index=True, return_inverse=True, return_counts=True))


def _correlate_every_factor(
    cov: np.ndarray, standard: Callable[[], np.ndarray], shape: tuple[int, ...]
) -> np.ndarray:
    """``L·std`` over every column of the Cholesky factor, its zeros too."""
    out = np.zeros((*shape, cov.shape[0]))
    if np.any(cov):
        chol, std = np.linalg.cholesky(cov), standard().reshape(*out.shape)
        for b in range(cov.shape[0]):
            out += std[..., b : b + 1] * chol[:, b]
    return out


def _group_sums_by_add_at(group: np.ndarray, values: np.ndarray, size: int) -> np.ndarray:
    out = np.zeros((size, *values.shape[1:]))
    np.add.at(out, group, values)
    return out


def _per_agent_by_add_at(n: int, receivers: np.ndarray, terms: np.ndarray) -> np.ndarray:
    return _group_sums_by_add_at(receivers, terms, n)


def _half_edges_by_int64(
    n: int, e0: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    tail = np.concatenate([e0[:, 0], e0[:, 1]])
    head = np.concatenate([e0[:, 1], e0[:, 0]])
    order = np.argsort(tail, kind="stable")
    edge = order % max(e0.shape[0], 1)
    return tail[order], head[order], np.searchsorted(tail[order], np.arange(n + 1)), edge


def _never_sure(
    dirs: np.ndarray, padded: np.ndarray, first: np.ndarray, counts: np.ndarray
) -> np.ndarray:
    return np.zeros(counts.shape[0], dtype=bool)


def _union_find_forests(
    n: int, lo: np.ndarray, hi: np.ndarray, order: np.ndarray, healthy: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The batch's forests by the Python union-find, as the leader took them before."""
    size = healthy.shape[0]
    rank, member = np.nonzero(healthy[:, order].T)  # edge-major: members keep the order
    edge = order[rank]
    base = member * n
    chosen, parent = leader.mst._union_find_scan(size * n, base + lo[edge], base + hi[edge])
    tree = np.zeros(healthy.shape, dtype=bool)
    tree[member[chosen], edge[chosen]] = True
    return tree, leader.mst._roots(np.asarray(parent, dtype=np.int64)).reshape(size, n)


def rigidity_per_epoch(epochs: int) -> None:
    print(
        f"rigidity check per epoch, 10,000 agents, {epochs} epochs, each mask ranked afresh, "
        "CPU ms; loss 10 % per link, Bernoulli or in bursts (Gilbert-Elliott p 1/30, r 0.3); "
        "before: growth in rounds of numpy, every candidate by SVD, half-edges by a 64-bit "
        "sort; after: compiled rounds, a determinant bound first, a 16-bit radix sort"
    )
    print(
        f"{'team':34} {'rigid':>5} {'before ms':>9} {'max':>6} "
        f"{'after ms':>8} {'max':>6} {'LU':>6} {'ratio':>6}"
    )
    print("(LU: epochs that reached the whole framework's pinned stiffness + R_U's check)")
    for family, d in teams():
        for redundancy in (0.1, 0.5):
            for loss, network in (("Bernoulli", LOSS), ("bursty", BURSTY)):
                s = family_team(family, d, redundancy, epochs, network)
                masks = healthy_masks(s, epochs)
                x, edges = s.offsets, s.edge_array
                rounds, spread = growth_rounds(x, edges), spans_without_any(x)
                times = np.zeros((2, epochs))
                answers: list[list[tuple[int | None, bool]]] = [[], []]
                counted = [0, 0]  # the whole framework's stiffness, R_U's; after
                for k, mask in enumerate(masks):  # the two paths alternate: the same load
                    for path in (0, 1):
                        calls.clear()
                        with Before() if path == 0 else contextlib.nullcontext():
                            t = time.process_time()
                            answer = rank_under_mask(x, edges, rounds, mask, spread)
                            times[path, k] = (time.process_time() - t) * 1e3
                        answers[path].append(answer)
                        if path == 1:
                            whole = calls.count(pinned_stiffness_definite.__name__)
                            counted[0] += whole
                            counted[1] += len(calls) - whole
                before, after = times
                if answers[0] != answers[1]:
                    raise SystemExit(f"{family} {d}-D: the two paths disagree")
                print(
                    f"{f'{family} {d}-D, {redundancy:.0%} spare, {loss}':34} "
                    f"{sum(r for _, r in answers[1]):5d} {before.mean():9.1f} {before.max():6.0f} "
                    f"{after.mean():8.1f} {after.max():6.0f} {f'{counted[0]}+{counted[1]}':>6} "
                    f"{before.mean() / after.mean():6.2f}",
                    flush=True,
                )


calls: list[str] = []


def _counted(stiffness: Callable[..., bool]) -> Callable[..., bool]:
    """``stiffness``, each call's name kept in :data:`calls` (the stiffness's epochs)."""

    def counted(*args: Any) -> bool:
        calls.append(stiffness.__name__)
        return stiffness(*args)

    return counted


rigidity_check.pinned_stiffness_definite = _counted(rigidity_check.pinned_stiffness_definite)
rigidity_check.outside_held = _counted(rigidity_check.outside_held)


def exact_against_svd(sizes: tuple[int, ...], masks: int) -> None:
    print(
        "the large-formation path (rank_under_mask) against the dense SVD of the whole "
        f"rigidity matrix, {masks} masks per team (edges lost at 1 %, 5 %, 30 %), seed 1"
    )
    print(f"{'team':30} {'agents':>6} {'masks':>5} {'rigid':>5} {'ranked':>6} {'agree':>5}")
    rng = np.random.default_rng(SEED)
    for family, d in teams():
        for n in sizes:
            for redundancy in (0.1, 0.5):
                if family == "henneberg":
                    s = henneberg_team(n, seed=SEED, redundancy=redundancy)
                else:
                    s = FAMILIES[family](n, d, redundancy, seed=SEED)
                x, edges = s.offsets, s.edge_array
                rounds, spread = growth_rounds(x, edges), spans_without_any(x)
                need = expected_rigidity_rank(n, d)
                rigid = ranked = agree = 0
                for k in range(masks):
                    mask = rng.random(len(edges)) >= (0.01, 0.05, 0.3)[k % 3]
                    want = rigidity_rank(x, edges[mask])
                    rank, is_rigid = rank_under_mask(x, edges, rounds, mask, spread)
                    rigid += want == need
                    ranked += rank is not None
                    agree += is_rigid == (want == need) and rank in (want, None)
                print(
                    f"{f'{family} {d}-D, {redundancy:.0%} spare':30} {n:6d} {masks:5d} "
                    f"{rigid:5d} {ranked:6d} {agree:5d}",
                    flush=True,
                )
                if agree != masks:
                    raise SystemExit(f"{family} {d}-D, {n} agents: not the SVD's answer")


def simulate_families(epochs: int) -> None:
    print(
        f"formation simulate, 10,000 agents, 10 % and 50 % spare, 10 % loss per link, Bernoulli "
        f"or bursty (Gilbert-Elliott p 1/30, r 0.3), {epochs} epochs (a 2-epoch run first), "
        "epochs per second of CPU; before and after alternate, positions equal to the bit"
    )
    print(f"{'team':34} {'before /s':>9} {'after /s':>9} {'ratio':>6}")
    for family, d in teams():
        for redundancy in (0.1, 0.5):
            for loss, network in (("Bernoulli", LOSS), ("bursty", BURSTY)):
                s = family_team(family, d, redundancy, epochs, network)
                simulate(s.with_overrides(epochs=2), seed=SEED)
                rates, positions = [], []
                for path in (0, 1):
                    with Before() if path == 0 else contextlib.nullcontext():
                        start = time.process_time()
                        result = simulate(s, seed=SEED)
                        rates.append(epochs / (time.process_time() - start))
                    positions.append(result.positions)
                if not np.array_equal(*positions):
                    raise SystemExit(f"{family} {d}-D: the two paths' positions differ")
                print(
                    f"{f'{family} {d}-D, {redundancy:.0%} spare, {loss}':34} {rates[0]:9.2f} "
                    f"{rates[1]:9.2f} {rates[1] / rates[0]:6.2f}",
                    flush=True,
                )


def simulate_rates(quick: bool) -> None:
    print("formation simulate (in process), epochs per second; baseline: 100 agents, this run")
    print(f"{'agents':>7} {'epochs':>7} {'epochs/s':>9} {'ratio':>7}")
    base = None
    for n, epochs in ((100, 200), (1000, 100), (10_000, 20 if quick else 50)):
        s = team(n, epochs=epochs)
        simulate(s.with_overrides(epochs=2), seed=SEED)
        start = time.perf_counter()
        simulate(s, seed=SEED)
        rate = epochs / (time.perf_counter() - start)
        base = base or rate
        print(f"{n:7d} {epochs:7d} {rate:9.1f} {rate / base:7.3f}", flush=True)


def leader_epoch(epochs: int) -> None:
    print("the leader's epoch (tree, BLUE estimates, rigidity), 10,000 agents, 2-D, this run")
    s = team(10_000, epochs=epochs)
    plan = plan_batch(s, [SEED], epochs=epochs)
    leader = Leader(s, HealthyRigidity(s.offsets, s.edge_array))
    known = np.asarray(plan.on_time)  # (E, 1, L)
    z = np.repeat(
        (s.offsets[s.directed_links[:, 1] - 1] - s.offsets[s.directed_links[:, 0] - 1])[None],
        1,
        axis=0,
    )
    times = []
    for k in range(epochs):
        t = time.perf_counter()
        leader.epochs(known[k], z, s.offsets[s.reference_agent - 1], covariances=False)
        times.append(time.perf_counter() - t)
    ms = np.array(times) * 1e3
    print(
        f"mean {ms.mean():.1f} ms, p50 {np.median(ms):.1f} ms, max {ms.max():.1f} ms over {epochs} epochs",
        flush=True,
    )


def sweep_cells(quick: bool) -> None:
    print(
        "batched sweep (run_batch, 8 seeds, hold, no detail), cells per second; baseline: 100 agents"
    )
    base = None
    for n in (100, 1000):
        s = team(n, epochs=50 if quick else 100)
        seeds = list(range(1, 9))
        start = time.perf_counter()
        run_batch(plan_batch(s, seeds), "hold", detail=False)
        rate = len(seeds) / (time.perf_counter() - start)
        base = base or rate
        print(f"{n:7d} agents: {rate:8.2f} cells/s, ratio {rate / base:.3f}", flush=True)


def report_and_replay(epochs: int, tmp: Path) -> None:
    print(
        f"report, recording and scene, 10,000 agents (scenarios/large/team10k.toml), {epochs} epochs"
    )
    s = Scenario.from_file(ROOT / "scenarios/large/team10k.toml").with_overrides(epochs=epochs)
    result = simulate(s, seed=SEED)
    start = time.perf_counter()
    write_report_from([result], tmp / "from-sim")
    print(f"report from the simulation: {time.perf_counter() - start:.1f} s", flush=True)
    mcap = tmp / "run.mcap"
    write_synthetic(mcap, result)  # what the recorder writes of such a run
    size = mcap.stat().st_size / 1e6
    start = time.perf_counter()
    run = load_run(mcap)
    print(
        f"load_run of its recording ({size:.0f} MB, {len(run.states):,} states): "
        f"{time.perf_counter() - start:.1f} s",
        flush=True,
    )
    start = time.perf_counter()
    write_report(mcap, tmp / "from-mcap")
    print(f"report from the recording: {time.perf_counter() - start:.1f} s", flush=True)
    x = result.positions[-1]
    start = time.perf_counter()
    scene = scene_update(epochs, 0, x, s.edge_array, s.offsets, s.reference_agent)
    encoded = scene.encode()
    print(
        f"one epoch's scene: {time.perf_counter() - start:.2f} s, {len(encoded) / 1e6:.1f} MB",
        flush=True,
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--quick", action="store_true", help="fewer epochs")
    p.add_argument("--rigidity-only", action="store_true", help="only the rigidity rows")
    p.add_argument("--simulate-only", action="store_true", help="only simulate on each team family")
    p.add_argument("--exact-only", action="store_true", help="only the SVD check, to 1,000 agents")
    p.add_argument(
        "--team",
        action="append",
        default=[],
        choices=[f"{f}-{d}" for f, d in teams()],
        help="only this team's rows (repeatable), e.g. henneberg-2",
    )
    args = p.parse_args()
    ONLY.extend(args.team)
    print(
        f"seed {SEED}; peak RSS of this process so far is in /proc; python {sys.version.split()[0]}"
    )
    if args.rigidity_only:
        rigidity_per_epoch(20 if args.quick else 100)
        return
    if args.simulate_only:
        simulate_families(20 if args.quick else 100)
        return
    if args.exact_only:
        exact_against_svd((200,) if args.quick else (200, 1000), 3 if args.quick else 6)
        return
    with tempfile.TemporaryDirectory() as tmp:
        load_times(Path(tmp))
    rigidity_per_epoch(20 if args.quick else 100)
    simulate_families(20 if args.quick else 100)
    simulate_rates(args.quick)
    leader_epoch(10 if args.quick else 30)
    sweep_cells(args.quick)
    with tempfile.TemporaryDirectory() as tmp:
        report_and_replay(3 if args.quick else 10, Path(tmp))
    print(
        f"peak RSS of the bench: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB"
    )


if __name__ == "__main__":
    main()
