"""An agent's ROS 2 body, fed bad poses by a robot over real Zenoh sessions (rmw_zenoh's
format, two peers on 127.0.0.1): a pose that is not finite, or further than the body could
move, is counted and not used; no usable pose for the timeout, and the body is lost."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator

import pytest
import zenoh

from agent.body import RobotBodies
from body import open_body_link
from formation.errors import BodyLost
from formation.scenario import Scenario
from shell import session_config
from testkit.zenoh_peer import free_port

pytestmark = pytest.mark.integration
pytest.importorskip("rosbags", reason="the ros2 extra")


@pytest.fixture
def sessions() -> Iterator[tuple[zenoh.Session, zenoh.Session]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    agent = zenoh.open(session_config("peer", None, endpoint))
    robot = zenoh.open(session_config("peer", endpoint, None))
    try:
        yield agent, robot
    finally:
        robot.close()
        agent.close()


def test_bad_poses_are_counted_and_not_used_and_a_silent_robot_is_lost(
    paper: Scenario, sessions: tuple[zenoh.Session, zenoh.Session]
) -> None:
    scenario = paper.with_overrides(body={"kind": "rmw_zenoh", "pose_timeout_s": 0.5})
    agent_session, robot_session = sessions
    bodies = RobotBodies(scenario, [2], "formation_agent_2", agent_session)
    robot = open_body_link("robot_2", scenario.body, robot_session)
    try:
        pose = robot.pose_publisher("/robot2/pose")
        period_ns = 1_000_000_000

        def send_until_counted(position: list[float], stamp_ns: int, count: str) -> None:
            before, deadline = bodies.counts[count], time.monotonic() + 10.0
            while bodies.counts[count] == before:  # until the sessions see each other
                assert time.monotonic() < deadline, f"no {count} counted"
                pose.publish(position, stamp_ns, 0.0)
                time.sleep(0.01)

        send_until_counted([0.5, 0.25], 0, "poses")
        assert bodies.wait_poses(0, 1.0) == {2: [0.5, 0.25]}
        send_until_counted([math.nan, 0.25], period_ns, "bad_poses")
        send_until_counted([math.inf, 0.0], period_ns, "bad_poses")
        send_until_counted([50.0, 0.25], period_ns, "jumps")  # 50 m in one epoch
        assert bodies.counts["bad_poses"] >= 2 and bodies.counts["jumps"] >= 1
        # none of them was used: epoch 1's pose never came, so the body is lost
        with pytest.raises(
            BodyLost,
            match=r"^agent 2: body lost: no usable pose on /robot2/pose for 0\.5 s "
            r"\(waiting for epoch 1\)$",
        ):
            bodies.wait_poses(1, 0.5)
        send_until_counted([0.5, 0.3], period_ns, "poses")
        assert bodies.wait_poses(1, 1.0) == {2: [0.5, 0.3]}
        # realtime: a pose older than the timeout is no pose
        time.sleep(0.6)  # the timeout itself is what is tested
        with pytest.raises(BodyLost, match=r"for 0\.5 s \(its newest pose\)$"):
            bodies.wait_poses(None, 0.5)
    finally:
        robot.close()
        bodies.close()
