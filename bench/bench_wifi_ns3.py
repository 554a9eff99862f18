"""The air model (netem/links/wifi) against ns-3 on the same phases: delivery and arrival time.

Run ``python -m bench wifi_ns3 [--phases K] [--seed S]`` with ns-3 installed (the optional extra
``[ns3]``; without it the benchmark says so and stops). Each case draws ``K`` phases from the
seed (positions, and each frame's readiness within the phase); the air model decides them here
and ns-3 runs them in its own process, the whole batch at once (``bench/wifi_ns3.py``, ns-3's
defaults, which are the model's). Printed per case: the delivery ratio (receptions over
addressed receivers) and the mean latency (arrival less readiness) of each, their difference
and ratio, and the time per phase of each (ns-3's inside its process: building the phase and
running it, without the import).

Cases: broadcasts of 200 B over UDP/IP (236 B MSDU) at 6 Mb/s by 5, 10, 20 and 40 agents
within 20 m, each once in a 20 ms phase (a 50 Hz state); the same by 20 agents spread over
60 m (pairs beyond the preamble threshold, hidden terminals); two agents 80 m apart on either
side of a third (a hidden-terminal pair) broadcasting within the same millisecond; unicast to
a neighbour by 10 agents within 20 m; broadcasts at 802.11b 11 Mb/s by 10 agents.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import subprocess
import sys
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from netem.links.wifi import BROADCAST, AirConfig, Frames, Key, decide_phase

SEED = 7
MSDU_BYTES = 236  # 200 B of UDP payload, UDP (8), IPv4 (20) and LLC/SNAP (8)
PERIOD_NS = 20_000_000


@dataclass(frozen=True)
class Case:
    name: str
    n: int
    radius_m: float  # agents uniform in a disc of this radius
    unicast: bool = False
    phy: str = "ofdm"
    rate_mbps: float = 6.0
    spread_ns: int = PERIOD_NS  # readiness uniform in [0, spread)
    hidden_pair: bool = False


CASES = [
    *(Case(f"broadcast, {n} agents within 20 m", n, 10.0) for n in (5, 10, 20, 40)),
    Case("broadcast, 20 agents within 60 m", 20, 30.0),
    Case("hidden pair 80 m apart, one frame each in 1 ms", 3, 0.0, spread_ns=1_000_000, hidden_pair=True),
    Case("unicast to a neighbour, 10 agents within 20 m", 10, 10.0, unicast=True),
    Case("broadcast at 802.11b 11 Mb/s, 10 agents", 10, 10.0, phy="dsss", rate_mbps=11.0),
]  # fmt: skip


def phase(case: Case, rng: np.random.Generator) -> tuple[np.ndarray, Frames]:
    if case.hidden_pair:
        positions = np.array([[0.0, 0.0], [40.0, 0.0], [80.0, 0.0]])
        return positions, Frames.of(
            [0, 2], BROADCAST, MSDU_BYTES, rng.integers(0, case.spread_ns, 2)
        )
    r = case.radius_m * np.sqrt(rng.uniform(0.0, 1.0, case.n))
    a = rng.uniform(0.0, 2 * np.pi, case.n)
    positions = np.column_stack([r * np.cos(a), r * np.sin(a)])
    receiver = (np.arange(case.n) + 1) % case.n if case.unicast else BROADCAST
    ready = rng.integers(0, case.spread_ns, case.n)
    return positions, Frames.of(np.arange(case.n), receiver, MSDU_BYTES, ready)


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


def run_ns3(batch: list[dict[str, object]]) -> tuple[list[dict[str, Any]], float]:
    started = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-m", "bench.wifi_ns3"],
        input=json.dumps(batch),
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0:
        raise SystemExit(f"ns-3 failed (exit {done.returncode}): {done.stderr[-2000:]}")
    lines = [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]
    return lines, time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=SEED)
    parser.add_argument("--phases", type=int, default=20, help="phases per case")
    parser.add_argument("--quick", action="store_true", help="5 phases per case")
    parser.add_argument(
        "--sinr-db",
        type=float,
        default=None,
        help="the model's SINR threshold (default: the PHY's)",
    )
    args = parser.parse_args()
    if importlib.util.find_spec("ns") is None:
        print("ns-3 is not installed (pip install '.[ns3]'): nothing to compare")
        return
    phases = 5 if args.quick else args.phases
    rng = np.random.default_rng(args.seed)
    plans = [[phase(case, rng) for _ in range(phases)] for case in CASES]
    batch = []
    for c, case in enumerate(CASES):
        for k, (positions, frames) in enumerate(plans[c]):
            batch.append(
                {
                    "phy": case.phy,
                    "rate_mbps": case.rate_mbps,
                    "x": positions[:, 0].tolist(),
                    "y": positions[:, 1].tolist(),
                    "sender": frames.sender.tolist(),
                    "receiver": frames.receiver.tolist(),
                    "payload_bytes": frames.payload_bytes.tolist(),
                    "ready_ns": frames.ready_ns.tolist(),
                    "seed": args.seed,
                    "run": c * 1000 + k + 1,
                }
            )
    ns3, ns3_s = run_ns3(batch)
    threshold = "the PHY's" if args.sinr_db is None else f"{args.sinr_db:g} dB"
    print(
        f"seed {args.seed}, {phases} phases per case; ns-3 3.44 (pip ns3) in one process: "
        f"{ns3_s:.1f} s with its import; the model's SINR threshold: {threshold}"
    )
    print(
        f"{'case':52} {'delivery model':>14} {'ns-3':>6} {'diff':>6} "
        f"{'latency model µs':>16} {'ns-3':>7} {'ratio':>6} {'ms/phase model':>14} {'ns-3':>7}"
    )
    index = 0
    for c, case in enumerate(CASES):
        config = AirConfig(phy=case.phy, rate_mbps=case.rate_mbps, sinr_threshold_db=args.sinr_db)  # type: ignore[arg-type]
        model_t = ns3_t = 0.0
        mine, theirs = np.zeros(3), np.zeros(3)
        for k, (positions, frames) in enumerate(plans[c]):
            t0 = time.perf_counter()
            out = decide_phase(config, positions, frames, Key(args.seed, c, k))
            model_t += time.perf_counter() - t0
            to = addressed(frames, positions.shape[0])
            mine += summary(out.arrival_ns, to, frames.ready_ns)
            arrival = np.full(to.shape, -1, dtype=np.int64)
            for t, node, f in ns3[index]["rx"]:
                if arrival[f, node] < 0:
                    arrival[f, node] = t
            theirs += summary(arrival, to, frames.ready_ns)
            ns3_t += ns3[index]["seconds"]
            index += 1
        d_mine, d_theirs = mine[0] / mine[1], theirs[0] / theirs[1]
        l_mine = mine[2] / max(mine[0], 1) / 1e3
        l_theirs = theirs[2] / max(theirs[0], 1) / 1e3
        print(
            f"{case.name:52} {d_mine:14.3f} {d_theirs:6.3f} {d_mine - d_theirs:+6.3f} "
            f"{l_mine:16.1f} {l_theirs:7.1f} {l_mine / max(l_theirs, 1e-9):6.3f} "
            f"{model_t / phases * 1e3:14.2f} {ns3_t / phases * 1e3:7.1f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
