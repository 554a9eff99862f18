"""The ROS 2 body: the extra's check, and the body's messages through rclpy's CDR."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from body import require_ros2
from body.ros2 import pose_message, pose_position, stamp_ns, twist_message
from formation.errors import Ros2Missing

REPO = Path(__file__).resolve().parents[3]


def test_a_missing_message_package_names_the_extra() -> None:
    with pytest.raises(
        Ros2Missing,
        match=r"^body\.kind = 'ros2' needs the ROS 2 Python packages \(no_such_msgs is not "
        r"installed\); install the extra: pip install 'formation-testbed\[ros2\]'$",
    ):
        require_ros2("body.kind = 'ros2'", "no_such_msgs/msg/Pose")


@pytest.fixture
def without_rclpy(tmp_path: Path) -> dict[str, str]:
    """An environment in which ``import rclpy`` fails, as where the extra is not installed."""
    shim = tmp_path / "shim" / "rclpy"
    shim.mkdir(parents=True)
    (shim / "__init__.py").write_text("raise ImportError(\"No module named 'rclpy'\")\n")
    return {"PYTHONPATH": str(shim.parent), "PYTHONSAFEPATH": "1", "PATH": "/usr/bin:/bin"}


@pytest.mark.parametrize(
    "command",
    [
        ["-m", "agent", "--id", "2", "--scenario"],
        ["-m", "testbed.cli", "ros2-plant"],
    ],
)
def test_a_ros2_body_without_the_extra_is_refused(
    tmp_path: Path, without_rclpy: dict[str, str], command: list[str]
) -> None:
    scenario = tmp_path / "robots.toml"
    scenario.write_text((REPO / "scenarios/paper.toml").read_text() + '\n[body]\nkind = "ros2"\n')
    done = subprocess.run(
        [sys.executable, *command, str(scenario)],
        env=without_rclpy,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 1, done.stderr
    assert "needs the ROS 2 Python packages (rclpy is not installed); install the extra: " in (
        done.stderr
    )
    assert "pip install 'formation-testbed[ros2]'" in done.stderr


# rosidl's type support imports lark-parser 0.12, which imports the deprecated sre_parse and sre_constants
@pytest.mark.filterwarnings(
    "ignore:module 'sre_(parse|constants)' is deprecated:DeprecationWarning"
)
def test_a_pose_and_a_twist_round_trip_through_rclpys_cdr_to_the_bit() -> None:
    pytest.importorskip("rclpy", reason="the ros2 extra")
    from geometry_msgs.msg import PoseStamped, Twist
    from nav_msgs.msg import Odometry
    from rclpy.serialization import deserialize_message, serialize_message

    x = [0.1 + 0.2, -1.0 / 3.0, 5e-324]
    for cls in (PoseStamped, Odometry):
        msg = pose_message(cls, x, 12 * 1_000_000_000 + 345, "world")
        back = deserialize_message(serialize_message(msg), cls)
        assert list(pose_position(back)) == x
        assert stamp_ns(back) == 12_000_000_345 and back.header.frame_id == "world"
    back = deserialize_message(serialize_message(twist_message(Twist, x[:2])), Twist)
    assert [back.linear.x, back.linear.y, back.linear.z] == [*x[:2], 0.0]
