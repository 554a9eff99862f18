"""Scenario events through the real processes (issue 20 item 1): a lockstep run with crash,
restart, leave and join equals ``formation simulate``, positions and drop decisions.

The launcher kills a crashing agent's process by PID once its last state is seen and starts
joining and restarted ones as the run nears their epoch; every process is ended by PID (the
``runs_dir`` fixture fails the test if one is left).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from formation.messages import Status
from formation.scenario import Scenario
from recorder import read_run
from testbed.runtime.launcher import launch
from testbed.runtime.outcome import RunOutcome
from testbed.sim.simulate import simulate

from .conftest import pid_alive, run_pids

pytestmark = pytest.mark.integration
SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios"


def assert_equals_the_simulator(outcome: RunOutcome, scenario: Scenario, strategy: str) -> None:
    sim = simulate(scenario, strategy=strategy)  # type: ignore[arg-type]
    team = scenario.membership
    seen = np.isfinite(outcome.positions).all(axis=2)  # (E + 1, n)
    expected = np.zeros_like(seen)
    for i in range(1, scenario.n + 1):
        for first, last in team.incarnations(i):
            expected[first : last + 1, i - 1] = True  # its states, up to its goodbye or crash
    np.testing.assert_array_equal(seen, expected)
    np.testing.assert_array_equal(outcome.positions[seen], sim.positions[seen])  # bit for bit
    np.testing.assert_array_equal(outcome.bodies, sim.positions)  # out of the team: where it was
    np.testing.assert_array_equal(outcome.formation_error, sim.formation_error)
    verdicts = {
        (d.source, d.target, d.epoch): d.verdict in ("pass", "duplicate")
        for d in outcome.decisions
        if d.link_class == "formation"
    }
    want = {
        (int(a), int(b), k): bool(sim.delivered[k, row])
        for k in range(scenario.epochs)
        for row, (a, b) in enumerate(scenario.directed_links)
        if team.present[k, a - 1] and team.present[k, b - 1]
    }
    assert verdicts == want, "a decision for every packet between agents taking part, no other"
    assert outcome.malformed == {}
    assert "losses" not in outcome.summary(), "an event is not an unplanned loss"
    incarnations = {str(i): team.incarnations(i) for i in range(1, scenario.n + 1)}
    assert outcome.summary()["team"] == incarnations, "who was in the team, by epoch"
    # the final errors are the team's at the end (not a departed body's), the simulator's too
    ours, theirs = outcome.summary(), sim.summary()
    for name in ("final_formation_error_m", "final_shape_error_m"):
        assert ours[name] == theirs[name], name
    if not team.present[-1].all():
        assert ours["final_formation_error_m"] != outcome.formation_error[-1]


def test_crash_restart_and_leave_equal_the_simulator(paper: Scenario, runs_dir: Path) -> None:
    scenario = paper.with_overrides(
        epochs=60,
        network={"formation_default": [{"model": "bernoulli", "p_loss": 0.2}],
                 # 2 -> 3 lost as agent 3 comes back: its new process has no value to hold
                 "links": [{"between": [2, 3], "direction": "forward",
                            "models": [{"model": "outage", "start": 30, "end": 33}]}]},
        events=[{"epoch": 15, "agent": 3, "action": "crash"},
                {"epoch": 30, "agent": 3, "action": "restart"},
                {"epoch": 45, "agent": 5, "action": "leave"}],
    )  # fmt: skip
    outcome = launch(scenario, strategy="hold", runs_dir=runs_dir, record=False)
    assert_equals_the_simulator(outcome, scenario, "hold")
    x3 = outcome.positions[:, 2]
    assert np.array_equal(x3[30], x3[15]), "restarted where its body stopped"
    assert outcome.supervision.fallbacks >= 0 and outcome.substitutions
    assert not any(pid_alive(p) for p in run_pids(runs_dir))


def test_a_join_and_every_other_event_equal_the_simulator(runs_dir: Path) -> None:
    scenario = Scenario.from_file(SCENARIOS / "events.toml")
    outcome = launch(scenario, strategy="estimate", runs_dir=runs_dir, record=False)
    assert_equals_the_simulator(outcome, scenario, "estimate")
    x6 = outcome.positions[:, 5]
    assert np.array_equal(x6[15], scenario.initial_positions()[5]), "starts where it is declared"
    # netem's live status names each event as it applies it, and who takes part from then.
    team = [json.loads(d) for _, d in outcome.supervision.team_events]
    assert [(t["event"], t["epoch"], t["team"], t["away"]) for t in team] == [
        ("join agent 6", 15, [1, 2, 3, 4, 5, 6], []),
        ("crash agent 3", 25, [1, 2, 4, 5, 6], [3]),
        ("restart agent 3", 40, [1, 2, 3, 4, 5, 6], []),
        ("leave agent 5", 60, [1, 2, 3, 4, 6], [5]),
    ]


def test_a_recorded_event_run_reports_who_was_in_the_team(runs_dir: Path) -> None:
    """``formation run`` records and reports events.toml: the Team section names each event,
    its transient and the spans; netem's statuses in the recording name them too."""
    proc = subprocess.run(
        [str(Path(sys.executable).with_name("formation")), "run", str(SCENARIOS / "events.toml"),
         "--runs-dir", str(runs_dir)],
        capture_output=True, text=True, timeout=300,
        env={k: v for k, v in os.environ.items() if k != "COLUMNS"},
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "lost at epoch" not in proc.stdout, "an event is not a loss"
    (run_dir,) = runs_dir.iterdir()
    text = (run_dir / "report.md").read_text()
    (summary,) = json.loads((run_dir / "summary.json").read_text())
    changes = [(c["epoch"], c["agent"], c["what"]) for c in summary["team_changes"]]
    assert changes == [(15, 6, "join"), (25, 3, "crash"), (40, 3, "restart"), (60, 5, "leave")]
    # the report's final errors are the team's at epoch 80, as formation simulate gives them
    sim = simulate(Scenario.from_file(SCENARIOS / "events.toml"), strategy="estimate").summary()
    for name in ("final_formation_error_m", "final_shape_error_m"):
        assert summary[name] == sim[name], name
    assert "1: 0–80; 2: 0–80; 3: 0–25, 40–80; 4: 0–80; 5: 0–60; 6: 15–80" in text
    verbs = {"join": "joins", "crash": "crashes", "restart": "restarts", "leave": "leaves"}
    for c in summary["team_changes"]:
        assert c["transient_epochs"] is not None and 0 <= c["transient_epochs"] <= 20
        assert (
            f"  - epoch {c['epoch']}: agent {c['agent']} {verbs[c['what']]} (scenario event); "
            f"shape error under 0.05 m after {c['transient_epochs']} epochs"
        ) in text
    assert (run_dir / "errors.png").stat().st_size > 10_000
    with (run_dir / "run.mcap").open("rb") as f:
        details = [
            json.loads(Status.model_validate_json(m.data).detail)
            for _, ch, m in make_reader(f).iter_messages()
            if ch.topic.endswith("/status/netem/0") and b"agent" in m.data
        ]
    assert [(d["event"], d["team"]) for d in details] == [
        ("join agent 6", [1, 2, 3, 4, 5, 6]), ("crash agent 3", [1, 2, 4, 5, 6]),
        ("restart agent 3", [1, 2, 3, 4, 5, 6]), ("leave agent 5", [1, 2, 3, 4, 6]),
    ]  # fmt: skip


def test_a_restarted_unicycle_faces_where_its_body_stopped(paper: Scenario, runs_dir: Path) -> None:
    # netem's answer to a restarted agent carries its last heading as well as its position
    scenario = paper.with_overrides(
        epochs=30,
        control={"dynamics": "unicycle", "gain": 0.1},
        events=[{"epoch": 10, "agent": 3, "action": "crash"},
                {"epoch": 20, "agent": 3, "action": "restart"}],
    )  # fmt: skip
    outcome = launch(scenario, strategy="hold", runs_dir=runs_dir)
    run = read_run(outcome.run_dir / "run.mcap")
    sim = simulate(scenario, strategy="hold")
    seen = np.isfinite(outcome.positions).all(axis=2)
    assert run.headings is not None and sim.headings is not None
    np.testing.assert_array_equal(outcome.positions[seen], sim.positions[seen])
    np.testing.assert_array_equal(run.headings[seen], sim.headings[seen])
    assert run.headings[20, 2] == run.headings[10, 2], "restarted facing where it stopped"
