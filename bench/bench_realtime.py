"""Realtime deadline-miss rate by team, layout and rate, with the load average next to each.

Misses of the testbed's own making (formation.deadlines), over the packets netem decided;
the layout ``picked`` is what ``formation run --mode realtime`` chooses on this machine
(testbed.runtime.layout). A miss rate is a fidelity figure, not a speed: there is no
baseline to divide by, but the load average says how busy the machine was around it.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from testbed.runtime.launcher import launch
from testbed.runtime.layout import realtime_layout
from testbed.sim.teams import henneberg_team

SEED = 1
EPOCHS = 100
CASES = [  # (label, agents, agent processes: None = one per agent, "picked" = the layout's)
    ("5 processes", 5, None),
    ("20 processes", 20, None),
    ("20 picked", 20, "picked"),
    ("100 picked", 100, "picked"),
]


def main() -> None:
    print(f"seed {SEED}, {EPOCHS} epochs, {os.cpu_count()} cores")
    print(
        f"{'case':14} {'Hz':>3} {'pools':>6} {'misses':>8} {'rate':>8}  {'load 1 min':>10}  causes"
    )
    with tempfile.TemporaryDirectory() as tmp:
        for hz in (10, 20):
            period = 1.0 / hz
            for label, n, layout in CASES:
                scenario = henneberg_team(n, seed=SEED, epochs=EPOCHS).with_overrides(
                    runtime={"mode": "realtime", "realtime_period_s": period}
                )
                packets = len(scenario.directed_links) + 2 * n
                pools = (
                    realtime_layout(n, period, None, packets).pools
                    if layout == "picked"
                    else layout
                )
                load = os.getloadavg()[0]
                s = launch(
                    scenario, seed=SEED, runs_dir=Path(tmp), pool=pools, record=False
                ).summary()
                misses = s["deadline_misses"]
                causes = ", ".join(f"{c} {k}" for c, k in misses["by_cause"].items() if k)
                print(
                    f"{label:14} {hz:>3} {pools or n:>6} {misses['total']:>8} "
                    f"{100 * s['deadline_miss_rate']:>7.2f}%  {load:>4.2f}-{os.getloadavg()[0]:<5.2f}"
                    f"  {causes or '-'}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
