"""One record, one summary: ``formation run``'s summary, its ``summary.json`` and ``formation
simulate`` agree to the last bit on events.toml, ``summary.json`` with the simulator's in every field;
so does a run of the value study's region where estimate pays (scenarios/distance_rigidity.toml).

The run is real processes on loopback (the launcher ``formation run`` calls, with the recorder),
its report written as ``formation run`` writes it; ``formation simulate --json`` runs as its own
process. Floats are compared with ``==`` (JSON keeps a float's repr, so its every bit).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from analysis import summarise
from formation.scenario import Scenario
from recorder import read_run
from recorder.reporting.report import write_report
from testbed.runtime.launcher import launch
from testbed.sim.batch import run_batch
from testbed.sim.plan import plan_batch
from testbed.sim.simulate import simulate
from testkit.summaries import summary_differences

from .conftest import pid_alive, run_pids

pytestmark = pytest.mark.integration
EVENTS = Path(__file__).resolve().parents[2] / "scenarios" / "events.toml"
FINAL = ("final_formation_error_m", "final_shape_error_m")


def test_run_summary_json_and_simulate_give_the_same_summary_to_the_bit(
    runs_dir: Path, seed: int
) -> None:
    scenario = Scenario.from_file(EVENTS)
    outcome = launch(scenario, strategy="estimate", seed=seed, runs_dir=runs_dir)
    write_report(outcome.run_dir / "run.mcap", outcome.run_dir)  # as formation run does
    (recorded,) = json.loads((outcome.run_dir / "summary.json").read_text())
    proc = subprocess.run(
        [str(Path(sys.executable).with_name("formation")), "simulate", str(EVENTS),
         "--strategy", "estimate", "--seed", str(seed), "--json"],
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    (simulated,) = json.loads(proc.stdout)
    assert (
        summary_differences(recorded, summarise(simulate(scenario, "estimate", seed).record()))
        == []
    )
    assert set(simulated) - set(recorded) == {"scenario_file", "fallbacks"}  # the command's own
    assert all(repr(simulated[k]) == repr(recorded[k]) for k in set(simulated) & set(recorded))
    ran = outcome.summary()
    assert not scenario.membership.published[-1].all(), "agent 5 has left: the team's errors"
    for name in FINAL:
        assert isinstance(ran[name], float), name
        assert repr(ran[name]) == repr(recorded[name]) == repr(simulated[name]), name
    # The sweep's rows come from the batch's arrays through the same rule.
    res = run_batch(plan_batch(scenario, [seed], scenario.epochs), "estimate", detail=False)
    formation, shape = res.team_errors()
    assert (float(formation[-1, 0]), float(shape[-1, 0])) == tuple(ran[n] for n in FINAL)
    assert ran["final_shape_error_m"] != float(np.asarray(outcome.shape_error)[-1])
    assert not any(pid_alive(p) for p in run_pids(runs_dir))


def test_where_estimation_pays_a_lockstep_run_is_the_simulator_s_to_the_bit(
    runs_dir: Path, seed: int
) -> None:
    """The value study's region where estimate pays (distance law, rigidity lost), as processes."""
    scenario = Scenario.from_file(EVENTS.with_name("distance_rigidity.toml")).with_overrides(
        epochs=100
    )
    outcome = launch(scenario, strategy="estimate", seed=seed, runs_dir=runs_dir)
    recorded = read_run(outcome.run_dir / "run.mcap")
    sim = simulate(scenario, "estimate", seed)
    np.testing.assert_array_equal(recorded.positions, sim.positions)
    assert summary_differences(summarise(recorded), summarise(sim.record())) == []
    assert summarise(recorded)["substitutions"] == 2 * (scenario.epochs - 1)  # 2–3 down, both ways
