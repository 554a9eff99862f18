"""The shared air in lockstep: real processes over Zenoh drop what the simulator drops, for the
same causes (the reports in their own phase or in the states'), and the recording shows a
hidden pair colliding at the agent between them."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from analysis import summarise
from formation.air import AIR_CAUSES
from formation.scenario import Scenario
from recorder import read_run
from recorder.reporting.report import air_lines
from testbed.runtime.launcher import launch
from testbed.sim.simulate import simulate

pytestmark = pytest.mark.integration

# Agents 1 and 3 are 80 m apart: each hears the other at -88 dBm, below the preamble
# threshold (-82 dBm) and the energy one (-62 dBm), so neither defers to the other; agent 2,
# 40 m from each, hears both at -79 dBm and loses both where they overlap.
HIDDEN_PAIR = """
name = "hidden_pair"
seed = 1
epochs = 10
reference_agent = 1
edges = [[1, 2], [2, 3], [1, 3]]
agents = [{ id = 1, offset = [0.0, 0.0] }, { id = 2, offset = [40.0, 5.0] },
          { id = 3, offset = [80.0, 0.0] }]

[control]
gain = 0.25

[noise]
sigma_m = 0.01

[network]
access_point = [40.0, -5.0]
air = { links = "all", start_spread_us = 1000.0 }
"""


@pytest.mark.parametrize(
    ("strategy", "air"),
    [
        ("estimate", ""),
        ("estimate", 'reports = "with_states", '),
        # hold never reads the estimates: their traffic stays off the air
        ("hold", 'reports = "with_states", estimation_traffic = "when_used", '),
    ],
)
def test_a_hidden_pair_collides_at_the_agent_between_them_as_the_simulator_says(
    tmp_path: Path, runs_dir: Path, strategy: str, air: str
) -> None:
    path = tmp_path / "hidden_pair.toml"
    path.write_text(HIDDEN_PAIR.replace("air = { ", "air = { " + air))
    scenario = Scenario.from_file(path)
    outcome = launch(scenario, strategy=strategy, runs_dir=runs_dir, record=True)
    sim = simulate(scenario, strategy=strategy)
    np.testing.assert_array_equal(outcome.positions, sim.positions)  # to the bit
    run = read_run(outcome.run_dir / "run.mcap")
    rec = run.decisions
    assert rec is not None
    made = sim.decisions_made()
    recorded = {
        (int(e), int(s), int(t)): (v != "drop", m if q == "air" else "")
        for e, s, t, v, m, q in zip(
            rec.epoch, rec.source, rec.target, rec.verdict, rec.model, rec.queue, strict=True
        )
    }
    simulated = {
        (int(e), int(s), int(t)): (v == "pass", m)
        for e, s, t, v, m in zip(
            made.epoch, made.source, made.target, made.verdict, made.model, strict=True
        )
    }
    assert recorded == simulated
    # the pair out of each other's range: below sensitivity both ways, every epoch
    assert {recorded[(k, 1, 3)] for k in range(10)} == {(False, "below_sensitivity")}
    # both lost at 2 in the same epoch: a collision of frames neither sender could sense
    both = [
        k for k in range(10) if recorded[(k, 1, 2)] == recorded[(k, 3, 2)] == (False, "collision")
    ]
    assert both
    delivered = (rec.queue == "air") & (rec.verdict != "drop")
    assert (rec.sojourn_ms[delivered] > 0).all()  # when each arrived in its phase [ms]
    # the summary splits the air's losses by cause, as recorded, and as the launcher saw them
    summary = summarise(run)
    dropped = Counter(m for v, m in recorded.values() if not v and m)
    assert summary["air_losses"] == {**dict.fromkeys(AIR_CAUSES, 0), **dropped}
    assert outcome.summary()["air_losses"] == summary["air_losses"]
    formation = summary["air"]["formation"]
    assert formation["took_air"] == 6 * 10 and formation["losses"]["collision"] > 0
    assert "| formation | 60 |" in "\n".join(air_lines(strategy, summary["air"]))
    assert ("report" in summary["air"]) == (strategy == "estimate")
