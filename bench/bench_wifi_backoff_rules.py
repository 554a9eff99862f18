"""Which DCF rule puts the air model above Bianchi's saturation throughput: switched one by one.

Run ``python -m bench wifi_backoff_rules [--rate R] [--n N] [--seed S] [--seeds K] [--frames F]``.
The Python reference loop (``netem.links.wifi.dcf``) runs ``saturation.saturated_phase`` as it
is and with two of the standard's rules replaced by Bianchi's chain's, an experiment that is
not in the product (docs/model.md §11):

- ``bianchi_decrement``: the slot in which another station's frame goes out counts a waiting
  station's backoff down by one, so one left at 1 sends in the first slot after the busy period
  (the standard and ns-3 count down only idle slots);
- ``no_ack_timeout``: a collider counts its backoff again DIFS after the collision, with the
  others, rather than DIFS after its ACKTimeout;
- ``both``.

For each: the throughput over Bianchi's (mean ± twice the standard error over the seeds), the
collided attempts over the attempts ``p`` and the attempts a station makes a slot ``τ`` (idle
slots and busy periods each counted as a slot), beside Bianchi's fixed point.
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from itertools import pairwise

import numpy as np
import numpy.typing as npt

from netem.links.wifi import AirConfig
from netem.links.wifi.dcf import TIMEOUT, Key, _Phase
from netem.links.wifi.medium import ACK
from netem.links.wifi.saturation import (
    UNREACHED_RETRY_LIMIT,
    backoff_stages,
    bianchi_tau,
    bianchi_throughput_bps,
    saturated_phase,
    steady_window_ns,
    throughput_bps,
)

PAYLOAD_BYTES = 1500


class BianchiDecrement(_Phase):
    """The busy slot counts a waiting station's backoff down by one."""

    def freeze(self, turned: npt.NDArray[np.int64]) -> None:
        if turned.shape[0] == 0:
            return
        ifs = np.where(self.eifs[turned], self.eifs_ns, self.difs_ns)
        start = self.idle_from[turned] + ifs
        done = np.where(self.now > start, (self.now - start) // self.slot_ns + 1, 0)
        self.counter[turned] = np.maximum(self.counter[turned] - done, 0)


class NoAckTimeout(_Phase):
    """A collider counts from the collision's end, on the others' slot boundaries."""

    def handle(self, kind: int, value: int) -> None:
        if kind == TIMEOUT and self.awaiting[value] and not self.ack_on_air[value]:
            if not self.busy[value]:
                ended = self.now - self.phy.ack_timeout_ns()
                self.idle_from[value] = max(int(self.idle_from[value]), ended)
            self.eifs[value] = False
            self.resolve(value, acked=False)
            return
        super().handle(kind, value)

    def plan(self, s: int) -> None:
        super().plan(s)
        if self.planned[s] < self.now:  # its backoff ended within the ACKTimeout: next boundary
            base = int(self.idle_from[s]) + self.difs_ns
            self.planned[s] = base + -(-(self.now - base) // self.slot_ns) * self.slot_ns


class Both(BianchiDecrement, NoAckTimeout):
    """Both of Bianchi's rules."""


RULES: dict[str, type[_Phase]] = {
    "standard": _Phase,
    "bianchi_decrement": BianchiDecrement,
    "no_ack_timeout": NoAckTimeout,
    "both": Both,
}


def run(rules: type[_Phase], config: AirConfig, n: int, per: int, seed: int) -> tuple[float, ...]:
    """``(throughput [bit/s], p, τ)`` of one saturated phase over ``throughput_bps``'s window."""
    positions, frames = saturated_phase(n, PAYLOAD_BYTES, per)
    phase = rules(config, positions, frames, Key(seed, 0, 0))
    outcome = phase.run(None)
    arrival = outcome.arrival_ns[np.arange(len(frames)), frames.receiver]
    start, end = steady_window_ns(arrival, frames.sender)
    together: dict[int, list[int]] = defaultdict(list)  # a collision's frames start together
    for tx in phase.medium.log:
        if tx.frame != ACK and start <= tx.start_ns < end:
            together[tx.start_ns].append(tx.end_ns)
    starts = sorted(together)
    attempts = sum(len(v) for v in together.values())
    collided = sum(len(v) for v in together.values() if len(v) > 1)
    phy = config.physical
    idle = 0
    for now, after in pairwise(starts):
        ends = together[now]
        busy_end = ends[0] + (phy.sifs_ns + phy.ack_ns(config.rate_kbps) if len(ends) == 1 else 0)
        idle += max(0, (after - busy_end - phy.difs_ns) // phy.slot_ns)
    slots = idle + len(starts) - 1
    throughput = throughput_bps(arrival, frames.sender, PAYLOAD_BYTES)
    return throughput, collided / attempts, attempts / (n * slots)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rate", type=float, default=6.0, help="[Mb/s]")
    parser.add_argument("--n", type=int, default=50)
    parser.add_argument("--seed", type=int, default=42)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--frames", type=int, default=120, help="a station's")
    args = parser.parse_args()
    config = AirConfig(rate_mbps=args.rate, retry_limit=UNREACHED_RETRY_LIMIT)
    chain = bianchi_throughput_bps(config, args.n, PAYLOAD_BYTES)
    tau, p = bianchi_tau(args.n, *backoff_stages(config))
    seeds = range(args.seed, args.seed + args.seeds)
    print(
        f"{args.rate:g} Mb/s, {args.n} stations, {args.frames} frames a station, seeds "
        f"{seeds.start}..{seeds.stop - 1}, the reference loop; Bianchi's fixed point: "
        f"{chain / 1e6:.3f} Mb/s, p {p:.3f}, τ {tau:.4f}"
    )
    print(f"   {'rules':<18} {'÷ Bianchi':>15} {'p':>6} {'τ':>7}")
    for name, rules in RULES.items():
        v = np.array([run(rules, config, args.n, args.frames, s) for s in seeds])
        ratio = v[:, 0] / chain
        two_se = 2 * ratio.std(ddof=1) / np.sqrt(len(seeds))
        print(
            f"   {name:<18} {ratio.mean():7.3f} ± {two_se:5.3f} {v[:, 1].mean():6.3f} "
            f"{v[:, 2].mean():7.4f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
