"""Realtime deadline-miss rate by team, layout and rate, with CPU per epoch per role.

Misses of the testbed's own making (formation.deadlines), over the packets netem decided;
the layout ``picked`` is what ``formation run --mode realtime`` chooses on this machine
(testbed.runtime.process_budget). A miss rate is a fidelity figure, not a speed: there is no
baseline to divide by, but the load average says how busy the machine was around it, and
``steal`` how much of the machine's CPU its hypervisor took meanwhile (testbed.runtime.steal): on a
shared VM, 10 % steal turned 0.3 % misses into 30 % (20 processes at 20 Hz, seed 1).
CPU per epoch per role: user + system time of the role's processes from the start of
epoch 0 until each ends (from /proc, sampled), over the epochs, in ms; ``agents`` is per
agent process.

``--quick`` runs the issue's two target cases only (20 processes at 20 Hz, 100 pooled at
10 Hz).
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import threading
from collections import defaultdict
from pathlib import Path

from bench.procfs import cpu_s
from testbed.runtime import steal
from testbed.runtime.launcher import launch
from testbed.runtime.process_budget import realtime_layout
from testbed.sim.team_generators import henneberg_team

SEED = 1
EPOCHS = 100
CASES = [  # (label, agents, agent processes: None = one per agent, "picked" = the layout's)
    ("5 processes", 5, None),
    ("20 processes", 20, None),
    ("50 processes", 50, None),
    ("100 picked", 100, "picked"),
    ("200 picked", 200, "picked"),
]
QUICK = [(20.0, "20 processes", 20, None), (10.0, "100 picked", 100, "picked")]


class CpuWatch:
    """The CPU time of a run's processes, sampled until each ends (the last sample counts)."""

    def __init__(self, runs_dir: Path) -> None:
        self.runs_dir, self.done = runs_dir, threading.Event()
        self.first: dict[str, float] = {}
        self.last: dict[str, float] = {}
        self.thread: threading.Thread | None = None

    def hook(self, run_id: str, endpoint: str) -> None:
        pids = json.loads((self.runs_dir / run_id / "pids.json").read_text())["pids"]
        self.thread = threading.Thread(target=self._watch, args=(pids,), daemon=True)
        self.thread.start()

    def _watch(self, pids: dict[str, int]) -> None:
        for name, pid in pids.items():  # start-up (imports, sessions) is not the run's
            self.first[name] = cpu_s(pid) or 0.0
        while not self.done.is_set():
            for name, pid in pids.items():
                if (t := cpu_s(pid)) is not None:
                    self.last[name] = t
            self.done.wait(0.1)

    def per_role_ms(self, epochs: int) -> dict[str, float]:
        self.done.set()
        if self.thread is not None:
            self.thread.join()
        roles: dict[str, list[float]] = defaultdict(list)
        for name, t in self.last.items():
            role = "agents" if name.startswith(("agent-", "pool-")) else name.split(".")[0]
            roles[role].append(t - self.first.get(name, 0.0))
        return {
            role: 1e3 * (sum(ts) / len(ts) if role == "agents" else sum(ts)) / epochs
            for role, ts in roles.items()
        }


def run_case(
    tmp: Path, hz: float, label: str, n: int, layout: str | None, zenoh_mode: str = "client"
) -> str:
    period = 1.0 / hz
    scenario = henneberg_team(n, seed=SEED, epochs=EPOCHS).with_overrides(
        runtime={"mode": "realtime", "realtime_period_s": period}
    )
    packets = len(scenario.directed_links) + 2 * n
    pools = realtime_layout(n, period, None, packets).pools if layout == "picked" else None
    load = os.getloadavg()[0]
    before = steal.ticks()
    watch = CpuWatch(tmp)
    s = launch(
        scenario, seed=SEED, runs_dir=tmp, pool=pools, record=False, on_started=watch.hook,
        zenoh_mode=zenoh_mode,
    ).summary()  # fmt: skip
    cpu = watch.per_role_ms(EPOCHS)
    stolen = 100 * (steal.share(before, steal.ticks()) or 0.0)
    misses = s["deadline_misses"]
    causes = ", ".join(f"{c} {k}" for c, k in misses["by_cause"].items() if k)
    cpu_txt = " ".join(f"{r} {cpu.get(r, 0):.1f}" for r in ("netem", "router", "leader", "agents"))
    return (
        f"{label:14} {hz:>4g} {pools or n:>6} {misses['total']:>7} "
        f"{100 * s['deadline_miss_rate']:>7.2f}%  {load:>4.1f}-{os.getloadavg()[0]:<4.1f} "
        f"{stolen:>5.1f}%  "
        f"{cpu_txt}  {causes or '-'}"
    )


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="the two target cases only")
    p.add_argument("--zenoh-mode", choices=("client", "peer"), default="client",
                   help="client: every packet through the router (the default); peer: direct")  # fmt: skip
    args = p.parse_args(argv)
    print(f"seed {SEED}, {EPOCHS} epochs, {os.cpu_count()} cores; CPU ms per epoch")
    print(f"{'case':14} {'Hz':>4} {'procs':>6} {'misses':>7} {'rate':>8}  {'load':>9} {'steal':>6}  "
          "CPU netem router leader agents(each)  causes")  # fmt: skip
    grid = QUICK if args.quick else [(hz, *c) for hz in (10.0, 20.0, 50.0) for c in CASES]
    with tempfile.TemporaryDirectory() as tmp:
        for hz, label, n, layout in grid:
            print(run_case(Path(tmp), hz, label, n, layout, args.zenoh_mode), flush=True)


if __name__ == "__main__":
    main()
