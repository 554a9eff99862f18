"""netem process: forwarded coordination packets per second, deciding and recording, vs pass-through.

Baseline: the same netem process with ``--passthrough`` (forwards every packet,
decides, closes and records nothing), in the same run. The workload is the
lockstep state phase of the paper scenario in steady state: one bench session
publishes ``x_i[k]`` for all 5 agents, epoch after epoch, as fast as netem takes
them (BLOCK). Pass-through forwards each on its out-links' keys (14 directed links,
``link/*/*/state``); lockstep netem decides every packet, sends each receiver one
delivery per epoch with its packets (``inbox/*/state``) and publishes the decision
records. A separate subscriber process counts the packets delivered. Seed: the
scenario's (1); no loss configured.

Reported: forwarded packets/s (wall clock, as the subscriber sees them) and netem's
own CPU time per forwarded packet (from /proc), which the sender and the counter,
sharing the machine's cores, do not disturb.

Distance models (issue 19; ``--distance`` runs only this): a ``logistic`` model on every
formation link, the agents on the pentagon drifting together (netem reads each state's
position; an epoch is clean when its positions put every link within reach), against
Bernoulli at the same mean loss in the same run.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from typing import Any

import numpy as np
import zenoh

from bench.netem_rig import ROOT, RUN, bench_scenario, netem_rig
from bench.procfs import cpu_s
from formation import keys
from formation.codec import attachment, encode, now_ns
from formation.linkmodels import Logistic
from formation.messages import CoordinationState
from formation.scenario import Scenario
from netem import link_lengths
from netem.links.closed_forms import expected_delivery_at
from netem.links.models import delivery_matrix

EPOCHS = 8_000
AGENTS = 5
LINKS = len(Scenario.from_file(ROOT / "scenarios/paper.toml").directed_links)  # 14
LINK_PAIRS = [
    (int(a), int(b)) for a, b in Scenario.from_file(ROOT / "scenarios/paper.toml").directed_links
]
OFFSETS = Scenario.from_file(ROOT / "scenarios/paper.toml").offsets
LOGISTIC = {"model": "logistic", "d50_m": 2.2, "width_m": 0.15}  # diagonals lose 12 %, sides 0


def position(k: int, i: int) -> list[float]:
    """Agent ``i``'s position at epoch ``k`` [m]: its place on the pentagon, drifting along x."""
    return [float(OFFSETS[i - 1, 0] + 1e-3 * k), float(OFFSETS[i - 1, 1])]


def _expected(epochs: int, network: dict[str, Any] | None) -> int:
    """Packets netem forwards on the formation links in ``epochs`` epochs (every one without loss)."""
    if not network:
        return epochs * LINKS
    scenario = bench_scenario(epochs, network)
    links = scenario.directed_links
    specs = [scenario.formation_link_models(int(a), int(b)) for a, b in links]
    x = [[position(k, i) for i in range(1, AGENTS + 1)] for k in range(epochs)]
    lengths = link_lengths(
        [[x[k][a - 1] for a, _ in links] for k in range(epochs)],
        [[x[k][b - 1] for _, b in links] for k in range(epochs)],
    )  # (epochs, L), as netem measures them
    return int(
        delivery_matrix(specs, scenario.seed, links, epochs, distances_m=lengths).copies.sum()
    )


def forward_rate(
    passthrough: bool, epochs: int = EPOCHS, network: dict[str, Any] | None = None
) -> tuple[float, float, float]:
    """(forwarded packets/s, netem CPU µs per forwarded packet, offered packets/s)."""
    expected = epochs * LINKS if passthrough else _expected(epochs, network)
    rig = netem_rig(epochs=epochs + 10, passthrough=passthrough, network=network)
    with rig as (session, endpoint, pid):
        counted = (
            [keys.link_state(RUN, "*", "*")] if passthrough
            else [keys.inbox(RUN, "*", "state"), "deliveries"]
        )  # fmt: skip
        counter = subprocess.Popen(
            [sys.executable, "-m", "bench.count_subscriber", endpoint, counted[0], str(expected),
             "60", *counted[1:]],
            stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        try:
            assert counter.stdout is not None
            if counter.stdout.readline().strip() != "ready":
                raise RuntimeError("the counting subscriber did not start")
            pubs = [
                session.declare_publisher(
                    keys.agent_state(RUN, i), congestion_control=zenoh.CongestionControl.BLOCK
                )
                for i in range(1, AGENTS + 1)
            ]
            time.sleep(0.5)  # the counter's subscription travels to netem through gossip
            payloads = [
                encode(CoordinationState(run_id=RUN, sender=f"agent/{i}", seq=k, epoch=k,
                                         stamp_ns=now_ns(), agent=i, position=position(k, i)))
                for k in range(epochs)
                for i in range(1, AGENTS + 1)
            ]  # fmt: skip
            cpu0 = cpu_s(pid) or 0.0
            start = time.time_ns()
            for n, payload in enumerate(payloads):
                k, i = divmod(n, AGENTS)
                pubs[i].put(payload, attachment=attachment(k, k, i + 1))
            sent_s = (time.time_ns() - start) / 1e9
            result = json.loads(counter.communicate(timeout=150)[0].strip().splitlines()[-1])
            cpu = (cpu_s(pid) or 0.0) - cpu0
            for pub in pubs:
                pub.undeclare()
        finally:
            if counter.poll() is None:
                counter.kill()
                counter.wait()
    count = result["count"]
    if count < expected:
        print(
            f"  warning ({'pass-through' if passthrough else 'lockstep'}): {count} of {expected} forwarded packets seen"
        )
    return (
        count / ((result["last_ns"] - start) / 1e9),
        1e6 * cpu / max(count, 1),
        len(payloads) / sent_s,
    )


def distance_against_bernoulli(repeats: int = 1, epochs: int = EPOCHS) -> None:
    """A distance model on every formation link against Bernoulli at its mean loss, same run:
    ``repeats`` pairs, interleaved in turn (the machine is shared), medians compared."""
    lengths = link_lengths(
        OFFSETS[[a - 1 for a, _ in LINK_PAIRS]], OFFSETS[[b - 1 for _, b in LINK_PAIRS]]
    )
    loss = float(np.mean(1.0 - expected_delivery_at(Logistic(**LOGISTIC), lengths)))
    bernoulli = {"formation_default": [{"model": "bernoulli", "p_loss": loss}]}
    ranged = {"formation_default": [LOGISTIC]}
    print(f"{epochs} lockstep epochs; logistic d50 {LOGISTIC['d50_m']} m, width "
          f"{LOGISTIC['width_m']} m on every formation link (mean loss {loss:.3f}); baseline: "
          f"Bernoulli at that loss, in the same run, {repeats} interleaved pair(s); seed 1")  # fmt: skip
    runs: dict[str, list[tuple[float, float, float]]] = {"Bernoulli": [], "logistic": []}
    for r in range(repeats):
        load = os.getloadavg()[0]
        pair = [("Bernoulli", bernoulli), ("logistic", ranged)]
        for name, network in pair if r % 2 == 0 else pair[::-1]:  # neither always first
            runs[name].append(got := forward_rate(False, epochs, network))
            print(f"  pair {r + 1} {name:9s} {got[0]:9.0f} forwarded/s  netem CPU "
                  f"{got[1]:5.2f} µs/packet  (offered {got[2]:.0f} states/s; load {load:.1f})")  # fmt: skip
    (b_rate, b_cpu), (d_rate, d_cpu) = (
        (float(np.median([g[0] for g in runs[n]])), float(np.median([g[1] for g in runs[n]])))
        for n in ("Bernoulli", "logistic")
    )
    print(
        f"Bernoulli {loss:.3f}   {b_rate:9.0f} forwarded/s  netem CPU {b_cpu:5.2f} µs/packet (median)"
    )
    print(f"logistic        {d_rate:9.0f} forwarded/s  netem CPU {d_cpu:5.2f} µs/packet (median)")
    print(f"ratio logistic / Bernoulli: rate {d_rate / b_rate:.2f} "
          f"({100 * (1 - d_rate / b_rate):.0f}% slower; target <= 25%), CPU per packet "
          f"{d_cpu / b_cpu:.2f}; load average {os.getloadavg()[0]:.1f} at the end")  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--distance", action="store_true", help="only the distance-model comparison")
    p.add_argument("--repeats", type=int, default=1, help="interleaved distance/Bernoulli pairs")
    p.add_argument("--epochs", type=int, default=EPOCHS, help="epochs of the distance comparison")
    args = p.parse_args()
    if args.distance:
        distance_against_bernoulli(args.repeats, args.epochs)
        return
    print(f"{EPOCHS} lockstep epochs of the paper scenario's state phase: {AGENTS} senders, "
          f"{LINKS} directed links; baseline: netem --passthrough in the same run")  # fmt: skip
    base, base_cpu, base_sent = forward_rate(passthrough=True)
    rate, cpu, sent = forward_rate(passthrough=False)
    print(f"pass-through   {base:9.0f} forwarded/s  netem CPU {base_cpu:5.2f} µs/packet  "
          f"(sender offered {base_sent:.0f} packets/s)")  # fmt: skip
    print(f"lockstep netem {rate:9.0f} forwarded/s  netem CPU {cpu:5.2f} µs/packet  "
          f"(sender offered {sent:.0f} packets/s)")  # fmt: skip
    print(f"ratio lockstep / pass-through: rate {rate / base:.2f}; "
          f"CPU per packet {cpu / base_cpu:.2f} (the loss logic costs {100 * (cpu / base_cpu - 1):.0f}% more)")  # fmt: skip
    # With loss most epochs are not clean and take netem's full path (per-packet decisions).
    lossy = {"formation_default": [{"model": "bernoulli", "p_loss": 0.1}]}
    rate, cpu, _ = forward_rate(passthrough=False, network=lossy)
    print(f"lockstep, Bernoulli 0.1 on every link (about 23% of epochs clean): {rate:9.0f} forwarded/s  "
          f"netem CPU {cpu:5.2f} µs/packet, {cpu / base_cpu:.2f}x pass-through")  # fmt: skip
    distance_against_bernoulli(args.repeats, args.epochs)


if __name__ == "__main__":
    main()
