"""The launcher's side of scenario events (issue 20 item 1), without processes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from formation.errors import RuntimeFailure
from formation.scenario import Scenario
from testbed.runtime.events import EventDriver, bodies
from testbed.runtime.outcome import RunOutcome


def test_events_need_one_process_per_agent(paper: Scenario) -> None:
    s = paper.with_overrides(events=[{"epoch": 5, "agent": 3, "action": "leave"}])
    with pytest.raises(RuntimeFailure, match=r"--pool 2 with scenario events"):
        EventDriver.check(s, 2)
    EventDriver.check(s, None)
    EventDriver.check(paper, 2)


def test_a_body_without_a_state_stays_where_it_was() -> None:
    x = np.full((4, 2, 2), np.nan)
    x[:, 0] = [[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0]]
    x[1, 1] = [5.0, 5.0]  # agent 2: a state at epoch 1 only
    x0 = np.array([[9.0, 9.0], [7.0, 7.0]])
    got = bodies(x, x0)
    np.testing.assert_array_equal(got[:, 0], x[:, 0])
    np.testing.assert_array_equal(got[:, 1], [[7.0, 7.0], [5.0, 5.0], [5.0, 5.0], [5.0, 5.0]])


def outcome_with(scenario: Scenario, positions: np.ndarray) -> RunOutcome:
    return RunOutcome(
        run_id="r", run_dir=Path("unused"), scenario=scenario, strategy="hold", seed=1,
        positions=positions, estimated_epochs=[], decisions=[], malformed={}, sent={}, pids=[],
        wall_s=0.0, substitutions=[],
    )  # fmt: skip


def test_the_summary_says_who_was_in_the_team_whenever_it_was_not_everyone(
    paper: Scenario,
) -> None:
    events = [
        {"epoch": 3, "agent": 2, "action": "leave"},
        {"epoch": 4, "agent": 5, "action": "crash"},
    ]
    s = paper.with_overrides(epochs=6, events=events)
    x = np.zeros((7, 5, 2))
    for i in range(1, 6):  # the states the agents publish: up to a leave's or crash's epoch
        out = [
            k
            for k in range(7)
            if not any(k in range(a, b + 1) for a, b in s.membership.incarnations(i))
        ]
        x[out, i - 1] = np.nan
    summary = outcome_with(s, x).summary()
    assert "losses" not in summary  # events are not losses
    assert summary["team"] == {"1": [(0, 6)], "2": [(0, 3)], "3": [(0, 6)], "4": [(0, 6)],
                               "5": [(0, 4)]}  # fmt: skip
    assert "team" not in outcome_with(paper.with_overrides(epochs=6), np.zeros((7, 5, 2))).summary()
