"""A unicycle robot's pose against the state its agent expects (agent.steering)."""

from __future__ import annotations

import math

import numpy as np

from agent.control import axle_centre
from agent.steering import confirmed_heading, confirmed_pose

LOOK = 0.05  # [m]


def test_a_yaw_that_agrees_to_its_rounding_keeps_the_unwrapped_heading() -> None:
    expected = 3.0 * math.pi + 0.1  # within an epoch the heading is not wrapped
    yaw = math.atan2(math.sin(expected), math.cos(expected))  # as a quaternion gives it back
    assert yaw != expected
    assert confirmed_heading(expected, yaw) == (expected, True)


def test_a_robot_that_turned_otherwise_is_followed_next_to_the_expected_heading() -> None:
    heading, agrees = confirmed_heading(2.0 * math.pi + 0.1, 0.3)
    assert not agrees and math.isclose(heading, 2.0 * math.pi + 0.3, abs_tol=1e-12)


def test_a_start_is_the_expected_state_where_the_pose_confirms_it_else_the_poses() -> None:
    x, th = np.array([[0.3, -1.2]]), np.array([2.5])
    centre = axle_centre(x, th, LOOK)[0].tolist()
    expected = (x[0].tolist(), 2.5)
    assert confirmed_pose(expected, centre, 2.5 + 1e-15, LOOK) == (x[0].tolist(), 2.5, True)
    moved = [centre[0] + 1e-3, centre[1]]  # 1 mm away: the robot's, not the expected
    point, heading, agrees = confirmed_pose(expected, moved, 2.5, LOOK)
    assert not agrees and heading == 2.5
    assert math.isclose(point[0], x[0, 0] + 1e-3, abs_tol=1e-12)
