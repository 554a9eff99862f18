"""Teams of 20 agent processes and 200 pooled agents complete 100 lockstep epochs in formation."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from formation.scenario import Scenario
from testbed.runtime.launcher import launch
from testbed.sim.simulate import simulate
from testbed.sim.team_generators import henneberg_team

pytestmark = [pytest.mark.integration, pytest.mark.slow]
SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios"


def test_twenty_agent_processes_reach_the_formation(runs_dir: Path) -> None:
    scenario = Scenario.from_file(SCENARIOS / "grid20.toml").with_overrides(epochs=100)
    outcome = launch(scenario, runs_dir=runs_dir, record=False)
    assert len([p for p in outcome.pids]) == 20 + 3  # router, netem, leader, 20 agents
    assert outcome.shape_error[0] > 0.1
    assert outcome.shape_error[-1] < 0.05  # 10 % Bernoulli loss on every link, estimate strategy
    np.testing.assert_allclose(outcome.positions, simulate(scenario).positions, rtol=0, atol=1e-9)


def test_two_hundred_agents_pooled_in_four_processes(runs_dir: Path) -> None:
    scenario = henneberg_team(200, epochs=100)
    outcome = launch(scenario, runs_dir=runs_dir, record=False, pool=4)
    assert len(outcome.pids) == 4 + 3
    assert outcome.shape_error[0] > 0.1
    assert outcome.shape_error[-1] < 0.05
    np.testing.assert_allclose(
        outcome.positions[-1], simulate(scenario).positions[-1], rtol=0, atol=1e-9
    )
