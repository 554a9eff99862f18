"""The launcher's side of scenario events (issue 20 item 1), without processes."""

from __future__ import annotations

import numpy as np
import pytest

from formation.errors import RuntimeFailure
from formation.scenario import Scenario
from testbed.runtime.events import EventDriver, bodies


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
