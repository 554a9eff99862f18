"""Faults (issue 20): how long the team takes to notice a killed agent, and a restarted one to
take part again; the lockstep rate of a run with a kill against the same run without, same run.

Noticing is netem's ``lost agent i`` status (after its 3 s liveliness grace, or at once when a
restarted process asks to rejoin first); taking part again is the first state of the restarted
agent the launcher sees.

``--events``: lockstep epochs/s of the default scenario with three scenario events (agent 3
crashes at epoch 500 and restarts at 1000, agent 5 leaves at 1250) against the same scenario
without events, the two interleaved ``--repeat`` times in the same run (issue 20 item 1).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from formation.scenario import Scenario
from testbed.runtime.launcher import launch
from testbed.runtime.outcome import RunOutcome

SEED = 1
EPOCHS = 1500
EVENTS = [
    {"epoch": 500, "agent": 3, "action": "crash"},
    {"epoch": 1000, "agent": 3, "action": "restart"},
    {"epoch": 1250, "agent": 5, "action": "leave"},
]
ROOT = Path(__file__).resolve().parents[1]


def run(runs: Path, restart: str | None) -> tuple[RunOutcome, float | None]:
    """The default scenario; ``restart`` None: no fault, else agent 3 killed 0.5 s in."""
    scenario = Scenario.from_file(ROOT / "scenarios/paper.toml").with_overrides(epochs=EPOCHS)
    killed: list[float] = []

    def hook(run_id: str, endpoint: str) -> None:
        if restart is None:
            return
        pid = json.loads((runs / run_id / "pids.json").read_text())["pids"]["agent-3"]

        def kill() -> None:
            time.sleep(0.5)
            os.kill(pid, signal.SIGKILL)
            killed.append(time.monotonic())

        threading.Thread(target=kill, daemon=True).start()

    outcome = launch(scenario, seed=SEED, runs_dir=runs, record=False, on_started=hook,
                     restart=restart or "no")  # type: ignore[arg-type]  # fmt: skip
    return outcome, (killed[0] if killed else None)


def noticed(outcome: RunOutcome, killed: float) -> tuple[float, Any]:
    """Seconds from the kill to netem's first status about agent 3, and that status."""
    for t, detail in outcome.supervision.team_events:
        d = json.loads(detail)
        if "agent 3" in d["event"]:
            return t - killed, d
    return float("nan"), None


def _ms(seconds: float | None) -> str:
    """A duration in ms, or why there is none (the launcher saw no state of the new process)."""
    return "no state back seen" if seconds is None else f"{1e3 * seconds:.0f} ms"


def events_rate(repeat: int) -> None:
    """Epochs/s with the three events against without, best of ``repeat`` interleaved runs."""
    paper = Scenario.from_file(ROOT / "scenarios/paper.toml").with_overrides(epochs=EPOCHS)
    with_events = paper.with_overrides(events=EVENTS)
    shown = ", ".join(f"{e['action']} {e['agent']} at {e['epoch']}" for e in EVENTS)
    print(f"seed {SEED}; default scenario (paper.toml), {EPOCHS} epochs, lockstep, real "
          f"processes; events: {shown}")  # fmt: skip
    walls: dict[str, list[float]] = {"without events": [], "with 3 events": []}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(repeat):
            for label, scenario in (("without events", paper), ("with 3 events", with_events)):
                out = launch(scenario, seed=SEED, runs_dir=Path(tmp), record=False)
                walls[label].append(out.wall_s)
    base, ev = min(walls["without events"]), min(walls["with 3 events"])
    for label, w in walls.items():
        print(f"{label}: {EPOCHS / min(w):.1f} epochs/s (best of {len(w)}: "
              f"{', '.join(f'{x:.2f}' for x in w)} s)")  # fmt: skip
    print(f"ratio with/without events: {(EPOCHS / ev) / (EPOCHS / base):.2f}x the epochs/s")


def main() -> None:
    p = argparse.ArgumentParser(prog="bench_faults", description=__doc__)
    p.add_argument("--events", action="store_true", help="only the scenario events' rate")
    p.add_argument("--repeat", type=int, default=2)
    args = p.parse_args()
    if args.events:
        events_rate(args.repeat)
        return
    print(f"seed {SEED}; default scenario (paper.toml), {EPOCHS} epochs, lockstep, real processes")
    with tempfile.TemporaryDirectory() as tmp:
        runs = Path(tmp)
        base, _ = run(runs, None)
        lost, t_lost = run(runs, "no")
        back, t_back = run(runs, "on-failure")
    rate = EPOCHS / base.wall_s
    assert t_lost is not None and t_back is not None
    s, d = noticed(lost, t_lost)
    loss = lost.summary()["losses"][0]
    print(f"baseline (no fault): {rate:.1f} epochs/s, {base.wall_s:.2f} s")
    print(f"kill -9 agent 3, no restart: netem noticed after {1e3 * s:.0f} ms "
          f"(lost at epoch {loss['epoch']}, noticed at epoch {d and d['epoch']}); "
          f"{EPOCHS / lost.wall_s:.1f} epochs/s, ratio {lost.wall_s / base.wall_s:.2f}x the wall time")  # fmt: skip
    s2, _ = noticed(back, t_back)
    loss2 = back.summary()["losses"][0]
    print(f"kill -9 agent 3, --restart on-failure: rejoin asked after {1e3 * s2:.0f} ms, "
          f"lost at epoch {loss2['epoch']}, back from epoch {loss2['back_from_epoch']} "
          f"({_ms(loss2['back_after_s'])} after the launcher saw it die); "
          f"ratio {back.wall_s / base.wall_s:.2f}x the wall time")  # fmt: skip
    events_rate(1)


if __name__ == "__main__":
    main()
