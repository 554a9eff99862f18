"""The simulator with ROS 2 bodies: each robot goes where the velocity it is sent takes it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from agent import body_step, body_velocity, held_velocity_step
from formation.scenario import Scenario
from testbed.sim.simulate import simulate

SCENARIOS = Path(__file__).resolve().parents[3] / "scenarios"


def test_a_robot_holds_the_velocity_it_is_sent_for_one_period() -> None:
    x = np.array([[0.09401229776087457, 1.0]])
    x_next = np.array([[0.02846745349737851, 1.5]])
    u = body_velocity(x, x_next, 0.3)
    np.testing.assert_array_equal(held_velocity_step(x, u, 0.3), x + 0.3 * u)
    # a velocity on the wire cannot always land on the float the agent computed: one bit off
    got = body_step(x, x_next, 0.3)
    assert np.abs(got - x_next).max() <= np.spacing(x_next).max() * 4
    assert (got != x_next).any()


def test_robots_move_the_formation_as_simulated_bodies_do_to_the_last_bits() -> None:
    grid = Scenario.from_file(SCENARIOS / "grid20.toml").with_overrides(epochs=30)
    robots = grid.with_overrides(body={"kind": "ros2"})
    a, b = simulate(grid), simulate(robots)
    assert (a.positions != b.positions).any()  # the velocity's round trip, in the last bits
    np.testing.assert_allclose(a.positions, b.positions, rtol=0, atol=1e-14)


def test_only_the_listed_agents_are_robots() -> None:
    grid = Scenario.from_file(SCENARIOS / "grid20.toml").with_overrides(epochs=5)
    some = simulate(grid.with_overrides(body={"kind": "ros2", "agents": list(range(2, 12))}))
    every = simulate(grid.with_overrides(body={"kind": "ros2"}))
    none = simulate(grid)
    first = some.positions[1]
    assert (first[1:11] != none.positions[1][1:11]).any()  # robots 2..11 moved as robots
    np.testing.assert_array_equal(first[1:11], every.positions[1][1:11])
    np.testing.assert_array_equal(
        first[[0, *range(11, 20)]], none.positions[1][[0, *range(11, 20)]]
    )
