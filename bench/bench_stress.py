"""Stress (issue 26): many runs beside busy loops, with readers that never read, to catch the rare.

Lockstep cases cycle through scenarios, strategies and seeds, each run as real processes with
one disturbance: none, a Zenoh subscriber attached from outside that never reads, a Foxglove
viewer that never reads (the recorder holds the run until it has subscribed), the recorder
stopped for ``PAUSE_S`` (SIGSTOP, then SIGCONT) half a second into the run, or an agent
killed mid-run (SIGKILL at agent 1's state of a third of the run, no restart). Every run must
finish and its bodies equal ``simulate``'s positions to the last bit. A killed agent's run equals
the simulator's with that agent crashed at its loss epoch (its own states up to it, and they
stop there: the crash event has it publish the state the kill took); a kill that fell inside
the epoch before, after the agent's state but before its report or one of its packets, is
compared up to that epoch, as no scenario event expresses it.
Runs without events or kills must have netem's every decision record. Every fifth case is a
realtime run whose books must balance (modelled + missed + delivered = sent, at most 100 %).

``python -m bench.bench_stress [--minutes M] [--busy N] [--json PATH]``: M minutes (default 3) of
cases beside N busy loops (default 2), a run that is not ok kept under ``--keep``; prints one line per run and the totals: runs, stalls
(no epoch for ``epoch_timeout_s``, or a start that never completed), other failures,
mismatches and unbalanced books.
"""

from __future__ import annotations

import argparse
import asyncio
import itertools
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from formation import keys
from formation.errors import RuntimeFailure
from formation.scenario import STRATEGIES, Scenario
from formation.topics import METRICS_TOPIC, SCENE_TOPIC, TF_TOPIC
from shell import session_config
from testbed.runtime.launcher import launch
from testbed.runtime.outcome import RunOutcome
from testbed.runtime.processes import free_port
from testbed.sim.simulate import simulate
from testkit import foxglove_client as fc
from testkit.run_watch import KillAtEpoch, read_pids

ROOT = Path(__file__).resolve().parents[1]
# (scenario file, epochs or None for its own): events has its own team changes, grid20 traffic
SCENARIOS = [("paper", 60), ("ring8", 80), ("events", None), ("octahedron3d", 60), ("grid20", 100)]
DISTURBANCES = ["none", "zenoh_never_reads", "foxglove_never_reads", "recorder_paused", "kill"]
PAUSE_S = 2.0  # the recorder stopped (SIGSTOP) this long, under the lease: slow, not gone
REALTIME_EVERY = 5
EPOCH_TIMEOUT_S = 60.0  # no epoch for this long is a stall


@dataclass(frozen=True)
class Case:
    scenario: str
    epochs: int | None
    strategy: str
    seed: int
    disturbance: str  # one of DISTURBANCES, or "realtime"

    def __str__(self) -> str:
        return f"{self.scenario} {self.strategy} s{self.seed} {self.disturbance}"

    def load(self) -> Scenario:
        sc = Scenario.from_file(ROOT / "scenarios" / f"{self.scenario}.toml")
        over: dict[str, Any] = {"seed": self.seed}
        if self.epochs is not None:
            over["epochs"] = self.epochs
        if self.disturbance == "realtime":
            over["runtime"] = {"mode": "realtime", "realtime_period_s": 0.05}
        return sc.with_overrides(**over)


def cases() -> Iterator[Case]:
    """Every scenario with each disturbance in turn, strategies and seeds rotating."""
    count = itertools.count()
    for seed in itertools.count(1):
        for (name, epochs), disturbance in itertools.product(SCENARIOS, DISTURBANCES):
            if disturbance == "kill" and name == "events":
                continue  # its own crash and restart are the faults there
            i = next(count)
            strategy = STRATEGIES[i % len(STRATEGIES)]
            if i % REALTIME_EVERY == REALTIME_EVERY - 1:
                realtime = STRATEGIES[(i // REALTIME_EVERY) % len(STRATEGIES)]
                yield Case("grid20", 100, realtime, seed, "realtime")
            yield Case(name, epochs, strategy, seed, disturbance)


class NeverReadingViewer(threading.Thread):
    """A Foxglove client that subscribes to the derived channels and then never reads."""

    def __init__(self, port: int) -> None:
        super().__init__(daemon=True)
        self.url = f"ws://127.0.0.1:{port}"
        self.stop = threading.Event()
        self.error: BaseException | None = None

    def run(self) -> None:
        try:
            asyncio.run(self._hold())
        except BaseException as exc:  # reported with the case, not lost in the thread
            self.error = exc

    async def _hold(self) -> None:
        ws = await fc.connect(self.url, 120.0)
        got = fc.Received()
        await fc.advertised(ws, got, {SCENE_TOPIC, TF_TOPIC, METRICS_TOPIC})
        idle = await fc.idle_subscriber(self.url, got.channels)
        await ws.close()
        while not self.stop.is_set():
            await asyncio.sleep(0.1)
        idle.transport.abort()


def run_case(case: Case, runs: Path) -> tuple[str, str]:
    """(verdict, detail): ok, stall, failure, mismatch or unbalanced."""
    sc = case.load()
    held: list[Any] = []
    recorder_args: tuple[str, ...] = ()
    hook: Callable[[str, str], None] | None = None
    viewer = kill = None
    if case.disturbance == "zenoh_never_reads":

        def hook(run_id: str, endpoint: str) -> None:
            session = zenoh.open(session_config("client", endpoint, None))
            held.extend([session, session.declare_subscriber(keys.everything(run_id))])

    elif case.disturbance == "foxglove_never_reads":
        port = free_port()
        recorder_args = ("--foxglove", str(port), "--foxglove-wait")
        viewer = NeverReadingViewer(port)
        viewer.start()
    elif case.disturbance == "recorder_paused":

        def hook(run_id: str, endpoint: str) -> None:
            pid = read_pids(runs / run_id)["recorder"]
            threading.Thread(target=pause, args=(pid,), daemon=True).start()

    elif case.disturbance == "kill":
        kill = KillAtEpoch(["agent-2"], sc.epochs // 3)
        hook = kill.hook(runs)
    record = "recorder" in case.disturbance or "foxglove" in case.disturbance or case.seed % 2 == 0
    try:
        outcome = launch(sc, strategy=case.strategy, runs_dir=runs, record=record,  # type: ignore[arg-type]
                         on_started=hook, epoch_timeout_s=EPOCH_TIMEOUT_S,
                         recorder_args=recorder_args)  # fmt: skip
    except RuntimeFailure as exc:
        text = str(exc).splitlines()[0]
        stalled = "no epoch finished" in text or "waiting for" in text
        return ("stall" if stalled else "failure"), text[:200]
    finally:
        if viewer is not None:
            viewer.stop.set()
            viewer.join(10.0)
        if kill is not None:
            kill.close()
        for session, subscriber in zip(held[::2], held[1::2], strict=True):
            subscriber.undeclare()  # first: a session closing waits on a full queue
            session.close()
    if case.disturbance == "realtime":
        return books(outcome)
    return compare(case, sc, outcome)


def pause(pid: int) -> None:
    time.sleep(0.5)
    os.kill(pid, signal.SIGSTOP)
    time.sleep(PAUSE_S)
    os.kill(pid, signal.SIGCONT)


def compare(case: Case, sc: Scenario, outcome: RunOutcome) -> tuple[str, str]:
    """The run against the simulator, to the last bit, and netem's records complete."""
    losses = outcome.summary().get("losses", [])
    if case.disturbance == "kill" and len(losses) != 1:
        return "failure", f"expected one loss, got {len(losses)} (the run ended before the kill?)"
    lost_at = losses[0]["epoch"] if losses else None
    if lost_at is not None:
        sc = sc.with_overrides(events=[{"epoch": lost_at, "agent": 2, "action": "crash"}])
    sim = simulate(sc, strategy=case.strategy)  # type: ignore[arg-type]
    if lost_at is not None and np.isfinite(outcome.positions[lost_at:, 1]).any():
        return "mismatch", f"agent 2 has states after its loss at {lost_at}"
    ran, want = outcome.bodies, sim.positions  # an agent out of the team: its body where it was
    if lost_at is not None:  # killed before its state of lost_at; the crash event publishes it
        ran, want = ran.copy(), want.copy()
        ran[lost_at:, 1] = want[lost_at:, 1] = 0.0
    partial = lost_at is not None and not sent_all(outcome, sc, 2, lost_at - 1)
    if partial:  # the kill fell inside epoch lost_at - 1, which no scenario event expresses
        ran, want = ran[:lost_at], want[:lost_at]
    if not np.array_equal(ran, want):
        where = np.argwhere(ran != want)
        first = tuple(int(i) for i in where[0][:2])
        return "mismatch", f"{len(where)} coordinates differ, first at (epoch, agent index) {first}"
    if case.disturbance != "kill" and not sc.events:
        got = Counter(d.link_class for d in outcome.decisions)
        expected = {
            "formation": len(sc.directed_links) * sc.epochs,
            "report": sc.n * sc.epochs,
            "estimate": sc.n * sc.epochs,
        }
        if got != expected:
            return "mismatch", f"decision records {dict(got)} != {expected}"
    if partial:
        return "ok", f"killed inside epoch {lost_at - 1}: equal up to it"
    return "ok", f"killed before epoch {lost_at}" if losses else ""


def sent_all(outcome: RunOutcome, sc: Scenario, agent: int, epoch: int) -> bool:
    """Whether ``agent`` sent all of ``epoch``: its report and a packet on each of its links."""
    mine = [d for d in outcome.decisions if d.source == agent and d.epoch == epoch]
    links = int((sc.directed_links[:, 0] == agent).sum())
    kinds = Counter(d.link_class for d in mine)
    return kinds["report"] == 1 and kinds["formation"] == links


def books(outcome: RunOutcome) -> tuple[str, str]:
    """Realtime: every packet sent is modelled lost, missed or delivered in time, once."""
    s = outcome.summary()
    modelled, missed = s["modelled_losses"]["total"], s["deadline_misses"]["total"]
    delivered, sent = s["delivered_in_time"], s["packets_sent"]
    line = f"modelled {modelled} + missed {missed} + delivered {delivered} = sent {sent}"
    if modelled + missed + delivered != sent or s["unaccounted"] or s["deadline_miss_rate"] > 1:
        return "unbalanced", f"{line}? unaccounted {s['unaccounted']}"
    return "ok", f"{line}, miss rate {s['deadline_miss_rate']:.2%}"


def busy_loops(n: int) -> list[subprocess.Popen[bytes]]:
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def main() -> None:
    p = argparse.ArgumentParser(prog="python -m bench.bench_stress", description=__doc__)
    p.add_argument("--minutes", type=float, default=3.0)
    p.add_argument("--busy", type=int, default=2)
    p.add_argument("--json", type=Path, help="write every run's verdict here")
    p.add_argument("--keep", type=Path, default=Path("runs/stress"), help="where a run that is "
                   "not ok leaves its folder (logs, pids.json; default runs/stress)")  # fmt: skip
    p.add_argument("--only", help="run only the cases whose name contains one of these "
                   "(comma-separated)")  # fmt: skip
    args = p.parse_args()
    deadline = time.monotonic() + 60 * args.minutes
    started = time.monotonic()
    results: list[dict[str, Any]] = []
    loops = busy_loops(args.busy)
    try:
        for case in cases():
            if time.monotonic() >= deadline:
                break
            if args.only and not any(part in str(case) for part in args.only.split(",")):
                continue
            t0 = time.monotonic()
            with tempfile.TemporaryDirectory() as tmp:
                try:
                    verdict, detail = run_case(case, Path(tmp))
                except Exception:  # a bug of the harness or the product: counted, and shown
                    verdict, detail = "failure", traceback.format_exc(limit=3).strip()[-300:]
                if verdict != "ok":
                    for run in Path(tmp).iterdir():
                        shutil.copytree(run, args.keep / run.name, dirs_exist_ok=True)
                        detail += f" ({args.keep / run.name})"
            took = time.monotonic() - t0
            results.append({"case": str(case), "verdict": verdict, "detail": detail, "s": took})
            print(f"#{len(results):3d} {case}: {verdict} {took:.1f} s {detail}", flush=True)
    finally:
        for loop in loops:  # by PID
            loop.kill()
            loop.wait()
    tally = Counter(r["verdict"] for r in results)
    minutes = (time.monotonic() - started) / 60
    print(
        f"\n{len(results)} runs in {minutes:.1f} min beside {args.busy} busy loops: "
        f"{tally['ok']} ok, {tally['stall']} stalls, {tally['failure']} failures, "
        f"{tally['mismatch']} mismatches, {tally['unbalanced']} unbalanced"
    )
    by_kind = Counter((r["case"].split()[-1], r["verdict"]) for r in results)
    for (kind, verdict), count in sorted(by_kind.items()):
        print(f"  {kind:22s} {verdict:10s} {count}")
    if args.json:
        args.json.write_text(json.dumps({"busy": args.busy, "minutes": minutes, "runs": results}))


if __name__ == "__main__":
    main()
