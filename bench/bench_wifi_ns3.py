"""The air model (netem/links/wifi) against ns-3 on the same phases: delivery and arrival time.

Run ``python -m bench wifi_ns3 [--phases K] [--seed S] [--speed | --saturation]`` with ns-3
installed (the optional extra ``[ns3]``; without it the benchmark says so and stops). Each case
draws ``K`` phases (times the case's own factor) from the seed: positions, and each frame's readiness within the phase. The
air model decides them here and ns-3 runs them in its own process, the whole batch at once
(``testkit.ns3_air``, ns-3's defaults, which are the model's). Printed per case: the delivery
ratio (receptions over addressed receivers) of each and their difference with twice the
standard error of the mean per-phase difference, the mean latency (arrival less readiness)
of each and their ratio, the attempts per frame of each (ns-3's data frames its PHYs sent),
and the CPU time per phase of each and their ratio (ns-3's inside
its process: building the phase and running it, without the import; the model's through
``decide_phase``, its compiled loop loaded before).

``--speed`` times only what a phase costs, on broadcasts by 5, 20, 40 and 50 agents and unicast by
50 (``K`` phases each, the best of three rounds on each side): CPU per phase on both sides
(ns-3's inside its process, as above), and wall time per phase as a caller sees it, the model's
call against ns-3 as a backend in its own process, its import done, a reply per phase (the gap
between one phase's reply and the next's on the pipe; the requests are written ahead, so a
phase's request costs ns-3 no wait).

``--saturation`` runs ``saturation.saturated_phase`` (802.11a, 1,500 B, 5 to 50 stations at 6
and 54 Mb/s, three seeds) in both, and prints each one's throughput over Bianchi's and over
the form ns-3 validates its DCF with (``saturation.bianchi_ns3_reference_bps``), ± twice the
standard error over the seeds.

Cases (docs/model.md §11): broadcasts of 200 B over UDP/IP (236 B MSDU) at 6 Mb/s by 2 to 50
agents within 20 m, each once in a 20 ms phase (a 50 Hz state); 20 agents spread over 60 m
(hidden terminals); two agents 80 m apart on either side of a third (a hidden-terminal pair)
sending within 1 ms (2 ms for 1,500 B); unicast to a neighbour by 2, 10 and 50 agents; 100 B
and 1,500 B payloads at 6 and 54 Mb/s; two agents near the edge of reception (46-56 m at
6 Mb/s, where the preamble is no longer detected; 30-40 m at 54 Mb/s, where the SNR no longer
carries the rate); broadcasts at 802.11b 11 Mb/s.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import importlib.util
import json
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from netem.links.wifi import BROADCAST, AirConfig, Frames, Key, decide_phase, load_compiled_loop
from netem.links.wifi.saturation import (
    UNREACHED_RETRY_LIMIT,
    bianchi_ns3_reference_bps,
    bianchi_throughput_bps,
    saturated_phase,
    throughput_bps,
)
from testkit.ns3_air import arrivals, phase_request, run_ns3

SEED = 7
MSDU_BYTES = 236  # 200 B of UDP payload, UDP (8), IPv4 (20) and LLC/SNAP (8)
PERIOD_NS = 20_000_000


@dataclass(frozen=True)
class Case:
    name: str
    n: int
    radius_m: float = 10.0  # agents uniform in a disc of this radius
    unicast: bool = False
    phy: str = "ofdm"
    rate_mbps: float = 6.0
    msdu_bytes: int = MSDU_BYTES
    spread_ns: int = PERIOD_NS  # readiness uniform in [0, spread)
    hidden_pair: bool = False
    apart_m: tuple[float, float] | None = None  # two agents this far apart (uniform)
    phases: int = 1  # times --phases


CASES = [
    *(Case(f"broadcast, {n} agents within 20 m", n) for n in (2, 5, 10, 20, 40, 50)),
    Case("broadcast, 20 agents within 60 m", 20, 30.0),
    Case("hidden pair 80 m apart, one frame each in 1 ms", 3, spread_ns=1_000_000, hidden_pair=True, phases=10),
    Case("hidden pair, 1500 B", 3, msdu_bytes=1536, spread_ns=2_000_000, hidden_pair=True, phases=10),
    *(Case(f"unicast to a neighbour, {n} agents within 20 m", n, unicast=True) for n in (2, 10, 50)),
    Case("broadcast, 20 agents, 100 B", 20, msdu_bytes=136),
    Case("broadcast, 20 agents, 1500 B", 20, msdu_bytes=1536, phases=4),
    Case("broadcast, 20 agents, 1500 B, 54 Mb/s", 20, rate_mbps=54.0, msdu_bytes=1536),
    Case("broadcast, 20 agents, 100 B, 54 Mb/s", 20, rate_mbps=54.0, msdu_bytes=136),
    Case("unicast, 10 agents, 1500 B, 54 Mb/s", 10, unicast=True, rate_mbps=54.0, msdu_bytes=1536),
    Case("edge: 2 agents 46-56 m apart, 6 Mb/s", 2, apart_m=(46.0, 56.0), phases=10),
    Case("edge: unicast 2 agents 46-56 m apart", 2, unicast=True, apart_m=(46.0, 56.0), phases=10),
    Case("edge: 2 agents 30-40 m apart, 54 Mb/s", 2, rate_mbps=54.0, apart_m=(30.0, 40.0), phases=10),
    Case("broadcast at 802.11b 11 Mb/s, 10 agents", 10, phy="dsss", rate_mbps=11.0),
]  # fmt: skip


SPEED_CASES = [
    *(Case(f"broadcast, {n} agents within 20 m", n) for n in (5, 20, 40, 50)),
    Case("unicast to a neighbour, 50 agents within 20 m", 50, unicast=True),
]


def phase(case: Case, rng: np.random.Generator) -> tuple[np.ndarray, Frames]:
    if case.hidden_pair:
        positions = np.array([[0.0, 0.0], [40.0, 0.0], [80.0, 0.0]])
        return positions, Frames.of(
            [0, 2], BROADCAST, case.msdu_bytes, rng.integers(0, case.spread_ns, 2)
        )
    if case.apart_m is not None:
        positions = np.array([[0.0, 0.0], [rng.uniform(*case.apart_m), 0.0]])
    else:
        r = case.radius_m * np.sqrt(rng.uniform(0.0, 1.0, case.n))
        a = rng.uniform(0.0, 2 * np.pi, case.n)
        positions = np.column_stack([r * np.cos(a), r * np.sin(a)])
    receiver = (np.arange(case.n) + 1) % case.n if case.unicast else BROADCAST
    ready = rng.integers(0, case.spread_ns, case.n)
    return positions, Frames.of(np.arange(case.n), receiver, case.msdu_bytes, ready)


def addressed(frames: Frames, n: int) -> np.ndarray:
    """(frames, n): which agents each frame is for."""
    to = np.zeros((len(frames), n), dtype=bool)
    for f in range(len(frames)):
        if frames.receiver[f] == BROADCAST:
            to[f] = True
            to[f, frames.sender[f]] = False
        else:
            to[f, frames.receiver[f]] = True
    return to


def summary(arrival: np.ndarray, to: np.ndarray, ready: np.ndarray) -> tuple[int, int, float]:
    got = to & (arrival >= 0)
    latency = (arrival - ready[:, None])[got]
    return int(got.sum()), int(to.sum()), float(latency.sum())


def requests(
    cases: list[Case], plans: list[list[tuple[np.ndarray, Frames]]], seed: int
) -> list[dict[str, Any]]:
    return [
        phase_request(
            case.phy,
            case.rate_mbps,
            positions,
            frames.sender,
            frames.receiver,
            frames.payload_bytes,
            frames.ready_ns,
            seed,
            c * 100_000 + k + 1,
        )
        for c, case in enumerate(cases)
        for k, (positions, frames) in enumerate(plans[c])
    ]


def streamed_ns3(batch: list[dict[str, Any]]) -> tuple[list[dict[str, Any]], np.ndarray]:
    """ns-3's replies, and when each reached this process [s]: ns-3 as a backend."""
    with tempfile.TemporaryFile("w+") as errors:
        process = subprocess.Popen(
            [sys.executable, "-m", "testkit.ns3_air"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=errors,
            text=True,
        )
        assert process.stdin is not None and process.stdout is not None
        process.stdin.write(json.dumps(batch))
        process.stdin.close()
        replies, times = [], []
        for line in process.stdout:
            if line.startswith("{"):
                times.append(time.perf_counter())
                replies.append(json.loads(line))
        if process.wait() != 0:
            errors.seek(0)
            raise RuntimeError(f"ns-3 failed (exit {process.returncode}): {errors.read()[-2000:]}")
    return replies, np.array(times)


def speed(seed: int, phases: int, rounds: int = 3) -> None:
    rng = np.random.default_rng(seed)
    plans = [[phase(case, rng) for _ in range(phases)] for case in SPEED_CASES]
    batch = requests(SPEED_CASES, plans, seed)
    # one phase first, not counted: ns-3's first phase also compiles its C++ through cppyy
    replies, came = streamed_ns3(batch[-1:] + batch * rounds)
    replies, came = replies[1:], came[1:]
    load_compiled_loop()
    print(
        f"what a phase costs, seed {seed}, {phases} phases a case, best of {rounds} rounds on "
        f"each side, ns3 {ns3_version()}, numba {numba_version()}: CPU (ns-3's inside its "
        "process) and wall as a caller sees it (ns-3 a backend process, its import done, the "
        "gap between its replies, the first phase of each case left out)"
    )
    print(
        f"{'case':46} {'CPU ms model':>12} {'ns-3':>7} {'ratio':>6} "
        f"{'wall ms model':>13} {'ns-3':>7} {'ratio':>6}"
    )
    cases = len(SPEED_CASES)
    model = np.full((cases, 2), np.inf)  # best CPU, wall [s] a phase
    ns3 = np.full((cases, 2), np.inf)
    for r in range(rounds):
        for c, case in enumerate(SPEED_CASES):
            config = AirConfig(phy=case.phy, rate_mbps=case.rate_mbps)  # type: ignore[arg-type]
            cpu, wall = 0.0, 0.0
            for k, (positions, frames) in enumerate(plans[c]):
                t0, w0 = time.process_time(), time.perf_counter()
                decide_phase(config, positions, frames, Key(seed, c, k))
                cpu += time.process_time() - t0
                wall += time.perf_counter() - w0
            model[c] = np.minimum(model[c], [cpu / phases, wall / phases])
            block = slice((r * cases + c) * phases, (r * cases + c + 1) * phases)
            ns3_cpu = sum(reply["seconds"] for reply in replies[block]) / phases
            ns3[c] = np.minimum(ns3[c], [ns3_cpu, float(np.diff(came[block]).mean())])
    for c, case in enumerate(SPEED_CASES):
        (model_cpu, model_wall), (ns3_cpu, ns3_wall) = model[c], ns3[c]
        print(
            f"{case.name:46} {model_cpu * 1e3:12.3f} {ns3_cpu * 1e3:7.2f} "
            f"{ns3_cpu / model_cpu:5.0f}× {model_wall * 1e3:13.3f} {ns3_wall * 1e3:7.2f} "
            f"{ns3_wall / model_wall:5.0f}×",
            flush=True,
        )


def ns3_version() -> str:
    return importlib.metadata.version("ns3")


def numba_version() -> str:
    return importlib.metadata.version("numba")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=SEED)
    parser.add_argument("--phases", type=int, default=40, help="phases per case (times its own)")
    parser.add_argument("--quick", action="store_true", help="5 phases per case")
    parser.add_argument(
        "--error-model", choices=["chunks", "threshold"], default="chunks", help="the model's"
    )
    parser.add_argument("--speed", action="store_true", help="only what a phase costs")
    parser.add_argument(
        "--saturation",
        action="store_true",
        help="instead: saturation against Bianchi's and ns-3's reference form, in both",
    )
    args = parser.parse_args()
    if importlib.util.find_spec("ns") is None:
        print("ns-3 is not installed (pip install '.[ns3]'): nothing to compare")
        return
    if args.saturation:
        saturation(args.seed)
        return
    if args.speed:
        speed(args.seed, 5 if args.quick else args.phases)
        return
    base = 5 if args.quick else args.phases
    rng = np.random.default_rng(args.seed)
    plans = [[phase(case, rng) for _ in range(base * case.phases)] for case in CASES]
    ns3, ns3_s = run_ns3(requests(CASES, plans, args.seed))
    load_compiled_loop()
    print(
        f"seed {args.seed} (ns-3 runs c·100000 + k + 1), {base} phases per case times its own; "
        f"ns-3 3.44 (pip ns3) in one process: {ns3_s:.1f} s with its import; the model's error "
        f"model: {args.error_model}; ± is twice the standard error of the mean per-phase "
        "difference"
    )
    print(
        f"{'case':40} {'phases':>6} {'delivery model':>14} {'ns-3':>6} {'diff':>13} "
        f"{'latency model µs':>16} {'ns-3':>7} {'ratio':>6} {'attempts model':>14} {'ns-3':>6} "
        f"{'ms/phase model':>14} {'ns-3':>7} "
        f"{'ns-3 ÷ model':>12}"
    )
    index = 0
    for c, case in enumerate(CASES):
        config = AirConfig(phy=case.phy, rate_mbps=case.rate_mbps, error_model=args.error_model)  # type: ignore[arg-type]
        model_t = ns3_t = 0.0
        mine, theirs = np.zeros(3), np.zeros(3)
        attempts = np.zeros(3)  # the model's, ns-3's, frames
        gaps = []
        for k, (positions, frames) in enumerate(plans[c]):
            t0 = time.process_time()
            out = decide_phase(config, positions, frames, Key(args.seed, c, k))
            model_t += time.process_time() - t0
            to = addressed(frames, positions.shape[0])
            ours = summary(out.arrival_ns, to, frames.ready_ns)
            ns3_arrival = arrivals(ns3[index], len(frames), positions.shape[0])
            reference = summary(ns3_arrival, to, frames.ready_ns)
            mine += ours
            theirs += reference
            attempts += (out.attempts.sum(), ns3[index]["data_tx"], len(frames))
            gaps.append((ours[0] - reference[0]) / max(ours[1], 1))
            ns3_t += ns3[index]["seconds"]
            index += 1
        k = len(plans[c])
        d_mine, d_theirs = mine[0] / mine[1], theirs[0] / theirs[1]
        spread = 2 * np.std(gaps, ddof=1) / np.sqrt(k)
        l_mine = mine[2] / max(mine[0], 1) / 1e3
        l_theirs = theirs[2] / max(theirs[0], 1) / 1e3
        print(
            f"{case.name:40} {k:6d} {d_mine:14.3f} {d_theirs:6.3f} "
            f"{d_mine - d_theirs:+6.3f}±{spread:5.3f} "
            f"{l_mine:16.1f} {l_theirs:7.1f} {l_mine / max(l_theirs, 1e-9):6.3f} "
            f"{attempts[0] / attempts[2]:14.3f} {attempts[1] / attempts[2]:6.3f} "
            f"{model_t / k * 1e3:14.2f} {ns3_t / k * 1e3:7.1f} {ns3_t / max(model_t, 1e-9):11.0f}×",
            flush=True,
        )


def saturation(seed: int, frames: int = 3000, seeds: int = 3) -> None:
    """The saturation throughput of the model and of ns-3 over Bianchi's and over ns-3's
    reference form, on the same phases."""
    plans = [
        (rate, n, s, *saturated_phase(n, 1500, max(30, frames // n)))
        for rate in (6.0, 54.0)
        for n in (5, 10, 20, 50)
        for s in range(seed, seed + seeds)
    ]
    batch = [
        phase_request(
            "ofdm", rate, x, f.sender, f.receiver, f.payload_bytes, f.ready_ns, s, 1, True
        )
        for rate, _, s, x, f in plans
    ]
    ns3, ns3_s = run_ns3(batch)
    print(
        f"saturation, 802.11a, 1500 B unicast, stations within a metre, {frames} frames a run, "
        f"seeds {seed}..{seed + seeds - 1} (ns-3's run 1); ns-3 3.44 (pip ns3): {ns3_s:.0f} s; "
        "throughput over Bianchi's and over ns-3's reference form "
        "(saturation.bianchi_ns3_reference_bps), mean ± twice its standard error over the seeds"
    )
    print(
        f"{'rate':>5} {'n':>3} {'Bianchi Mb/s':>12} {'ns-3 ref':>8} {'model/Bianchi':>13} "
        f"{'ns-3/Bianchi':>13} {'model/ref':>13} {'ns-3/ref':>13} {'attempts':>8} {'ns-3':>6}"
    )
    rows: dict[tuple[float, int], list[tuple[float, float, float, float]]] = {}
    for (rate, n, s, x, f), reply in zip(plans, ns3, strict=True):
        config = AirConfig(rate_mbps=rate, retry_limit=UNREACHED_RETRY_LIMIT)
        out = decide_phase(config, x, f, Key(s, 0, 0))
        to = np.arange(len(f)), f.receiver
        model = throughput_bps(out.arrival_ns[to], f.sender, 1500)
        theirs = throughput_bps(arrivals(reply, len(f), n)[to], f.sender, 1500)
        tries = (out.attempts.sum() / len(f), reply["data_tx"] / len(f))
        rows.setdefault((rate, n), []).append((model, theirs, *tries))
    for (rate, n), values in rows.items():
        v = np.array(values)
        mean, two_se = v.mean(axis=0), 2 * v.std(axis=0, ddof=1) / np.sqrt(len(v))
        chain = bianchi_throughput_bps(AirConfig(rate_mbps=rate), n, 1500)
        reference = bianchi_ns3_reference_bps(AirConfig(rate_mbps=rate), n, 1500)
        ratios = " ".join(
            f"{mean[k] / base:6.3f}±{two_se[k] / base:5.3f}"
            for base in (chain, reference)
            for k in (0, 1)
        )
        print(
            f"{rate:5g} {n:3d} {chain / 1e6:12.3f} {reference / 1e6:8.3f} {ratios} "
            f"{mean[2]:8.3f} {mean[3]:6.3f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
