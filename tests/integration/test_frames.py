"""A simulation gives the same DataFrames as a recording of the same run (``SimResult.frames()``
against ``recorder.load_run``): real processes on loopback, recorded, against ``simulate``.

Column for column; the values the model makes equal (states, estimates, netem's verdicts,
the metrics, the substitutions) to the bit.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from formation.scenario import Scenario
from recorder import load_run
from testbed.runtime.launcher import launch
from testbed.sim.simulate import simulate

from .conftest import pid_alive, run_pids

pytestmark = pytest.mark.integration

# What the simulator does not model: a packet's sequence number, delay and link state, and
# the recorder's live metric.
NOT_MODELLED = {
    "decisions": ["seq", "delay_ms", "model", "state"],
    "metrics": ["recorded_formation_error_m"],
}


def same(recorded: pd.DataFrame, simulated: pd.DataFrame, table: str) -> None:
    assert list(recorded.columns) == list(simulated.columns), table
    assert len(recorded) == len(simulated), table
    for column in recorded.columns:
        if column in NOT_MODELLED.get(table, []):
            continue
        a, b = recorded[column].to_numpy(), simulated[column].to_numpy()
        if a.dtype.kind == "f" or b.dtype.kind == "f":
            np.testing.assert_array_equal(a.astype(float), b.astype(float), err_msg=column)
        else:
            assert a.tolist() == b.tolist(), f"{table}.{column}"


EVENTS = Path(__file__).resolve().parents[2] / "scenarios" / "events.toml"


@pytest.mark.parametrize("case", ["lossy", "events"])
def test_a_simulation_s_frames_are_its_recording_s(
    paper: Scenario, runs_dir: Path, seed: int, case: str
) -> None:
    scenario = (
        paper.with_overrides(
            epochs=20,
            network={
                "formation_default": [{"model": "bernoulli", "p_loss": 0.2}],
                "control_default": [{"model": "bernoulli", "p_loss": 0.1}],
            },
        )
        if case == "lossy"
        else Scenario.from_file(EVENTS)  # agent 5 leaves: the team's rows and errors
    )
    outcome = launch(scenario, strategy="estimate", seed=seed, runs_dir=runs_dir)
    recorded = load_run(outcome.run_dir / "run.mcap")
    simulated = simulate(scenario, strategy="estimate", seed=seed).frames()
    assert recorded.skipped is not None and recorded.skipped.total == 0
    assert simulated.skipped is None
    if case == "lossy":
        assert len(recorded.substitutions) and (recorded.decisions["verdict"] == "drop").any()
    else:
        assert (recorded.metrics["agents"] < scenario.n).any()
    for table in ("states", "estimates", "decisions", "metrics", "substitutions"):
        same(getattr(recorded, table), getattr(simulated, table), table)
    assert not any(pid_alive(p) for p in run_pids(runs_dir))
