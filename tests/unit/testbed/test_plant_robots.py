"""The stepped plant's unicycles and the agents' inner loops, joined by poses as they travel
(the heading in a quaternion), equal the simulator's unicycle step to the bit; no ROS 2."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from agent import drive_unicycle
from agent.steering import InnerLoop, confirmed_pose
from body.ros2 import pose_message, pose_yaw
from formation.robots import initial_headings
from formation.scenario import Scenario
from testbed.plant.robots import Robots

NS_PER_S = 1_000_000_000


def pose_class() -> Any:
    """A stand-in for ``geometry_msgs/msg/PoseStamped``: the fields pose_message fills."""
    ns = SimpleNamespace
    return ns(
        header=ns(stamp=ns(sec=0, nanosec=0), frame_id=""),
        pose=ns(position=ns(x=0.0, y=0.0, z=0.0), orientation=ns(x=0.0, y=0.0, z=0.0, w=1.0)),
    )


def through_a_pose(robots: Robots, row: int) -> tuple[list[float], float]:
    """Robot ``row``'s axle centre and yaw as an agent reads them from its pose."""
    msg = pose_message(pose_class, robots.x[row].tolist(), 0, "world", robots.yaw(row))
    return [msg.pose.position.x, msg.pose.position.y], pose_yaw(msg)


@pytest.mark.parametrize("max_turn", [3.6, 0.5])
def test_stepped_unicycles_steered_pose_by_pose_equal_the_simulators_step(
    paper: Scenario, max_turn: float
) -> None:
    control = {"dynamics": "unicycle", "unicycle": {"max_turn_rad_s": max_turn}}
    scenario = paper.with_overrides(control=control, body={"kind": "ros2"})
    limits, period_s = scenario.control.unicycle.limits, scenario.control.period_s
    period_ns = round(period_s * NS_PER_S)
    plant = Robots.of(scenario)
    p, heading = scenario.initial_positions(), initial_headings(scenario.seed, scenario.n)
    for r in range(scenario.n):  # the first pose confirms where the scenario starts it
        start = (p[r].tolist(), float(heading[r]))
        assert confirmed_pose(start, *through_a_pose(plant, r), limits[2]) == (*start, True)
    rng = np.random.default_rng(7)
    clipped = 0
    for k in range(6):
        u = rng.normal(scale=0.15, size=(scenario.n, 2))  # [m/s]: some over the speed limit
        loops = [
            InnerLoop(u[[r]], p[[r]], heading[[r]], k * period_ns, (k + 1) * period_ns,
                      period_s, limits)
            for r in range(scenario.n)
        ]  # fmt: skip
        for r, loop in enumerate(loops):
            v, w = loop.twist()
            plant.command(r + 1, [v, 0.0], w)
        while not all(loop.done for loop in loops):
            assert plant.ready()
            plant.step()  # as the plant's node stamps a sub-step's pose
            stamp = plant.epoch * period_ns + plant.substep * period_ns // limits[3]
            for r, loop in enumerate(loops):
                twist = loop.on_pose(*through_a_pose(plant, r), stamp)
                if twist is not None:
                    plant.command(r + 1, [twist[0], 0.0], twist[1])
        p, heading, saturated = drive_unicycle(p, heading, u, period_s, limits)
        got = [loop.result() for loop in loops]
        assert [g[0] for g in got] == p.tolist()
        assert [g[1] for g in got] == heading.tolist()
        assert [g[2] for g in got] == saturated.tolist()
        assert sum(loop.yaw_taken for loop in loops) == 0
        clipped += int(saturated.sum())
    assert plant.epoch == 6 and plant.counts["steps"] == 6 * limits[3]
    assert clipped > 0  # the limits were reached, and counted alike


def test_the_stepped_plant_waits_for_the_robots_whose_agent_takes_part_and_holds_the_others(
    paper: Scenario,
) -> None:
    events = [{"epoch": 3, "agent": 5, "action": "crash"},
              {"epoch": 5, "agent": 5, "action": "restart"},
              {"epoch": 6, "agent": 4, "action": "leave"}]  # fmt: skip
    scenario = paper.with_overrides(events=events, epochs=8, body={"kind": "ros2"})
    plant = Robots.of(scenario)
    assert plant.starting(0) == {1, 2, 3, 4, 5}
    assert [plant.starting(k) for k in (3, 5, 6)] == [set(), {5}, set()]
    for k in range(8):
        team = scenario.membership.taking_part(k)
        out = {i: plant.x[i - 1].tolist() for i in range(1, 6) if i not in team}
        for i in team:
            plant.command(i, [0.01 * i, -0.02])
            assert plant.ready() == (i == team[-1])  # the last one taking part completes it
        plant.step()
        assert {i: plant.x[i - 1].tolist() for i in out} == out, "out of the team: where it was"
    assert plant.epoch == 8 and not plant.ready()
    assert plant.counts["commands"] == sum(
        len(scenario.membership.taking_part(k)) for k in range(8)
    )
