"""Capacity in lockstep: real processes drop, by queue, exactly what the simulator drops."""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from formation.scenario import STRATEGIES, Scenario
from testbed.runtime.launcher import launch
from testbed.sim.simulate import simulate

pytestmark = pytest.mark.integration


def constrained(paper: Scenario) -> Scenario:
    """The access point carries every control link at 30 kbit/s with room for 3 packets, and
    agent 2's radio 40 kbit/s with a tbf bucket; Bernoulli losses on the formation links."""
    network = paper.network.model_dump(by_alias=True)
    network["formation_default"] = [{"model": "bernoulli", "p_loss": 0.1}]
    # and 2 -> 4 delayed by an epoch now and then: a delayed packet crosses agent 2's radio too
    jitter = {"model": "delay", "epochs": 0, "jitter_epochs": 1}
    network["links"] = [*network["links"], {"between": [2, 4], "direction": "forward",
                                             "models": [jitter]}]  # fmt: skip
    network["capacity"] = [
        {"scope": "medium", "medium": "ap", "links": "control", "rate_bps": 30_000.0,
         "limit_packets": 3, "overhead_bytes": 42},
        {"scope": "radio", "agent": 2, "rate_bps": 40_000.0, "burst_bytes": 600,
         "limit_bytes": 1200, "policy": "oldest"},
        # alone in their queues, judged as they come: a backlog (1.02 s a state), in time
        {"scope": "link", "link": [1, 3], "rate_bps": 2_000.0, "limit_packets": 2},
        {"scope": "link", "link": [4, 1], "rate_bps": 11_000.0},
    ]  # fmt: skip
    return paper.with_overrides(network=network, epochs=25)


def assert_same_drops(scenario: Scenario, outcome: Any, sim: Any) -> None:
    """The run's positions and every packet's fate are the simulator's."""
    np.testing.assert_allclose(outcome.positions, sim.positions, rtol=0, atol=1e-9)
    got = {(d.source, d.target, d.link_class, d.epoch): d for d in outcome.decisions}
    n, links = scenario.n, scenario.directed_links
    for k in range(scenario.epochs):
        for row, (a, b) in enumerate(links):
            on_time = got[(a, b, "formation", k)].verdict in ("pass", "duplicate")
            assert on_time == sim.delivered[k, row], (a, b, k)
        for i in range(1, n + 1):
            assert (got[(i, 0, "report", k)].verdict != "drop") == sim.report_ok[k, i - 1]
            assert (got[(0, i, "estimate", k)].verdict != "drop") == sim.estimate_ok[k, i - 1]


@pytest.mark.parametrize("strategy", STRATEGIES)
def test_a_lockstep_run_with_capacity_equals_the_simulator(
    paper: Scenario, runs_dir: Path, strategy: str
) -> None:
    scenario = constrained(paper)
    outcome = launch(scenario, strategy=strategy, runs_dir=runs_dir, record=False)  # type: ignore[arg-type]
    sim = simulate(scenario, strategy=strategy)  # type: ignore[arg-type]
    assert_same_drops(scenario, outcome, sim)
    reasons = Counter(d.model for d in outcome.decisions if d.verdict == "drop")
    assert reasons["queue_full"] > 0 and reasons["queue_late"] > 0 and reasons["bernoulli"] > 0
    assert set(reasons) <= {"queue_full", "queue_late", "bernoulli", "outage"}  # paper: 1-2 down
    assert any(d.verdict == "delayed" for d in outcome.decisions)


def test_a_recorded_run_reports_its_queues_and_splits_its_losses(
    paper: Scenario, runs_dir: Path, tmp_path: Path
) -> None:
    import json

    from recorder import write_report

    scenario = constrained(paper).with_overrides(epochs=15)
    outcome = launch(scenario, strategy="estimate", runs_dir=runs_dir, record=True)
    report = write_report(outcome.run_dir / "run.mcap", tmp_path)
    summary = json.loads((tmp_path / "summary.json").read_text())
    by_model = Counter(d.model for d in outcome.decisions if d.verdict == "drop")
    (run,) = summary  # one run: a list of one summary
    assert run["loss_split"] == {
        "channel": by_model["bernoulli"] + by_model["outage"],
        "queue": by_model["queue_full"],
        "deadline": by_model["queue_late"],
    }
    assert outcome.summary()["loss_split"] == run["loss_split"]  # the launcher's, from what it saw
    ap = run["queues"]["medium ap"]
    control = [d for d in outcome.decisions if d.link_class != "formation"]
    assert ap["offered"] == len(control)  # every control packet the models passed, and none lost
    assert ap["passed"] == sum(d.verdict != "drop" for d in control)
    assert sum(ap["drops"].values()) == ap["offered"] - ap["passed"]
    assert ap["max_depth"] >= 3  # the limit: packets found it full
    assert "radio 2" in run["queues"]
    text = report.read_text()
    assert "## Capacity queues" in text and "| medium ap |" in text
    assert f"losses {run['loss_split']['channel']} channel" in text
    assert "![Capacity queues: depth over time](queues.png)" in text
    assert (tmp_path / "queues.png").stat().st_size > 0


def test_formation_run_says_its_losses_by_where(runs_dir: Path) -> None:
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[2]
    proc = subprocess.run(
        [sys.executable, "-m", "testbed.cli", "run", str(root / "scenarios/access_point.toml"),
         "--epochs", "8", "--no-record", "--runs-dir", str(runs_dir)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    said = " ".join((proc.stdout + proc.stderr).split())
    assert re.search(r"estimate: losses \d+ channel, \d+ queue \(full\), \d+ deadline", said), said


def test_events_through_the_queues_equal_the_simulator(paper: Scenario, runs_dir: Path) -> None:
    scenario = constrained(paper).with_overrides(
        epochs=40,
        events=[{"epoch": 10, "agent": 3, "action": "crash"},
                {"epoch": 20, "agent": 3, "action": "restart"},
                {"epoch": 30, "agent": 5, "action": "leave"}],
    )  # fmt: skip
    outcome = launch(scenario, strategy="hold", runs_dir=runs_dir, record=False)
    sim = simulate(scenario, strategy="hold")
    team = scenario.membership
    seen = np.isfinite(outcome.positions).all(axis=2)
    np.testing.assert_array_equal(outcome.positions[seen], sim.positions[seen])  # bit for bit
    got = {(d.source, d.target, d.link_class, d.epoch): d for d in outcome.decisions}
    for k in range(scenario.epochs):
        for row, (a, b) in enumerate(scenario.directed_links.tolist()):
            if team.present[k, a - 1] and team.present[k, b - 1]:
                on_time = got[(a, b, "formation", k)].verdict in ("pass", "duplicate")
                assert on_time == sim.delivered[k, row], (a, b, k)
        for i in range(1, scenario.n + 1):
            if team.present[k, i - 1]:
                assert (got[(i, 0, "report", k)].verdict != "drop") == sim.report_ok[k, i - 1]
                assert (got[(0, i, "estimate", k)].verdict != "drop") == sim.estimate_ok[k, i - 1]
    assert any(d.model.startswith("queue_") for d in outcome.decisions)


def test_queues_in_closed_form_equal_the_simulator(paper: Scenario, runs_dir: Path) -> None:
    """A netem-rate queue on every link: the states' fast or in time (judged in closed form),
    agent 2's estimates late: drops are the simulator's."""
    network = paper.network.model_dump(by_alias=True)
    network["formation_default"] = [{"model": "bernoulli", "p_loss": 0.05}]
    rates = {(4, 1): 11_000.0, (0, 2): 9_000.0}  # 0.19 s a state; 0.36 s an estimate, late
    control = [[i, 0] for i in range(1, 6)] + [[0, i] for i in range(1, 6)]
    network["capacity"] = [
        {"scope": "link", "link": [a, b], "rate_bps": rates.get((a, b), 1e9)}
        for a, b in paper.directed_links.tolist() + control
    ]
    scenario = paper.with_overrides(network=network, epochs=30)
    outcome = launch(scenario, strategy="estimate", runs_dir=runs_dir, record=False)
    assert_same_drops(scenario, outcome, simulate(scenario, strategy="estimate"))
    assert any(d.model == "queue_late" for d in outcome.decisions)
