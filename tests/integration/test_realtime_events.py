"""Scenario events in realtime: each agent takes part in its parts only, by the run's clock.

A join, a crash with its restart and a leave (``scenarios/events.toml``) on the wall clock:
the joiner's first state is the one of its epoch, the restarted agent's second part starts at
its epoch with the body where its first left it, the leaver stops, nothing is recorded twice
(no conflicts for the trust gate), and every packet netem decided is accounted for, including
those of the crashed part. Timing on a loaded machine is not asserted: a miss is a fidelity
figure (bench/bench_realtime.py).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from formation.scenario import load
from recorder import read_run
from testbed.runtime.launcher import launch

pytestmark = pytest.mark.integration


def test_join_crash_restart_and_leave_on_the_wall_clock(runs_dir: Path) -> None:
    # 62 epochs: the leave at 60 is in; a restart gets 15 epochs (2.25 s) to come up
    scenario = load("events").with_overrides(
        epochs=62, runtime={"mode": "realtime", "realtime_period_s": 0.15}
    )
    outcome = launch(scenario, strategy="hold", runs_dir=runs_dir)
    s = outcome.summary()
    team = scenario.membership
    run = read_run(outcome.run_dir / "run.mcap")
    # each agent's states recorded exactly in its parts: 6 from 15, 3 in 0-25 and 40-62, 5 to 60
    assert (run.present == team.published).all(), np.argwhere(run.present != team.published)
    assert run.recorded.skipped.total == 0, run.recorded.skipped.describe()
    seen = np.isfinite(outcome.positions).all(axis=2)
    assert (seen == team.published).all()
    # the restart took its body where its first part left it (netem's last state of it)
    (_, crashed), (again, _) = team.incarnations(3)
    assert (crashed, again) == (25, 40)
    assert np.array_equal(run.positions[again, 2], run.positions[crashed, 2])
    # the books balance: the crashed part's counts are in, nothing sent to an absent agent
    modelled, misses = s["modelled_losses"]["total"], s["deadline_misses"]["total"]
    assert modelled + misses + s["delivered_in_time"] == s["packets_sent"], s["deadline"]
    assert s["unaccounted"] == 0
