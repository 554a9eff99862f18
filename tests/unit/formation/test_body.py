"""A scenario's [body]: defaults, a ROS 2 body, and bad input naming file, field and value."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from formation.errors import ScenarioError
from formation.scenario import load, load_dict
from testkit.scenario_files import TRIANGLE, scenario_file


def write(tmp_path: Path, text: str) -> Path:
    return scenario_file(tmp_path, TRIANGLE + text)


def test_the_default_body_is_simulated(tmp_path: Path) -> None:
    s = load(write(tmp_path, ""))
    assert s.body.kind == "simulated"
    assert s.body.robots(s.n) == []


def test_a_ros2_body_for_every_agent_with_its_topics(tmp_path: Path) -> None:
    s = load(
        write(
            tmp_path,
            """
[body]
kind = "ros2"
pose_topic = "/tb{id}/odom"
pose_type = "nav_msgs/msg/Odometry"
scale = 0.5
pose_qos = { durability = "transient_local", depth = 1 }
""",
        )
    )
    assert s.body.robots(s.n) == [1, 2, 3]
    assert s.body.pose_topic_of(2) == "/tb2/odom"
    assert s.body.command_topic_of(3) == "/robot3/cmd_vel"
    assert s.body.pose_qos.durability == "transient_local" and s.body.pose_qos.depth == 1
    assert s.body.command_qos.reliability == "reliable"
    # stored with the run and read back the same
    again = write(tmp_path, "")
    again.write_text(s.to_toml())
    assert load(again).body == s.body


def test_a_ros2_body_for_some_agents(tmp_path: Path) -> None:
    s = load(write(tmp_path, '[body]\nkind = "ros2"\nagents = [3, 1]\n'))
    assert s.body.robots(s.n) == [1, 3]
    assert not s.body.has_robot(2)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        (
            'pose_topic = "/robot/pose"',
            r"bad\.toml: body\.pose_topic = '/robot/pose'; a topic template names the agent as \{id\}, \{index\} or \{name\}",
        ),
        (
            'command_topic = "/robot{id}/{kind}"',
            r"body\.command_topic = '/robot\{id\}/\{kind\}'; a topic template may only name \{id\}, \{index\} and \{name\}, got \['id', 'kind'\]",
        ),
        (
            'pose_topic = "/robot{id}//pose"',
            r"body\.pose_topic = '/robot\{id\}//pose'; not a ROS 2 topic name once filled in \('/robot1//pose'\)",
        ),
        (
            'pose_type = "geometry_msgs/msg/Pose"',
            r"body\.pose_type = 'geometry_msgs/msg/Pose'; unknown message type; expected one of "
            r"geometry_msgs/msg/PoseStamped, nav_msgs/msg/Odometry",
        ),
        (
            'command_type = "geometry_msgs/msg/TwistStamped"',
            r"body\.command_type = 'geometry_msgs/msg/TwistStamped'; unknown message type; "
            r"expected one of geometry_msgs/msg/Twist$",
        ),
        ('kind = "dds"', r"body\.kind = 'dds'; Input should be 'simulated', 'ros2' or 'rmw_zenoh'"),
        ("agents = [4]", r"body\.agents\[0\] = 4; agent does not exist \(agents are 1\.\.3\)"),
        ("agents = [2, 2]", r"body\.agents = \[2, 2\]; an agent is listed twice"),
        ("scale = 0.0", r"body\.scale = 0\.0; Input should be greater than 0"),
        ("pose_timeout_s = -1.0", r"body\.pose_timeout_s = -1\.0; Input should be greater than 0"),
        ("domain_id = 300", r"body\.domain_id = 300; Input should be less than or equal to 232"),
        ('frame_id = ""', r"body\.frame_id = ''; a frame id is a non-empty name"),
        (
            'pose_qos = { reliability = "sometimes" }',
            r"body\.pose_qos\.reliability = 'sometimes'; Input should be 'reliable' or 'best_effort'",
        ),
        ("pose_qos = { depth = 0 }", r"body\.pose_qos\.depth = 0; Input should be greater than"),
        ("topic = '/x{id}'", r"body\.topic = '/x\{id\}'; unknown field"),
        (
            'transforms = [{ agent = 4, frame_id = "odom4" }]',
            r"body\.transforms\[0\]\.agent = 4; agent does not exist \(agents are 1\.\.3\)",
        ),
        (
            'agents = [1]\ntransforms = [{ agent = 2, frame_id = "odom2" }]',
            r"body\.transforms\[0\]\.agent = 2; no ROS 2 robot has this agent \(body\.agents\)",
        ),
        (
            'transforms = [{ agent = 2, frame_id = "a" }, { agent = 2, frame_id = "b" }]',
            r"body\.transforms\[0\]\.agent = 2; a robot has one transform; it is given twice",
        ),
        (
            'transforms = [{ agent = 2, frame_id = "world" }]',
            r"body\.transforms\[0\]\.frame_id = 'world'; the world frame itself",
        ),
        (
            'transforms = [{ agent = 2, frame_id = "" }]',
            r"body\.transforms\[0\]\.frame_id = ''; a frame id is a non-empty name",
        ),
        (
            'transforms = [{ agent = 2, frame_id = "odom2", offset_m = [1.0] }]',
            r"body\.transforms\[0\]\.offset_m = \[1\.0\]; Tuple should have at least 2 items",
        ),
    ],
)
def test_bad_body_settings_name_file_field_and_value(tmp_path: Path, text: str, match: str) -> None:
    kind = "" if text.startswith("kind") else 'kind = "ros2"\n'
    with pytest.raises(ScenarioError, match=match):
        load(write(tmp_path, f"[body]\n{kind}{text}\n"))


def test_a_ros2_unicycle_runs_in_lockstep_and_in_realtime(tmp_path: Path) -> None:
    # lockstep steps its inner loop through the stepped plant (docs/robots.md)
    unicycle = '[control]\ndynamics = "unicycle"\n[body]\nkind = "ros2"\n'
    for mode in ("lockstep", "realtime"):
        scenario = load(write(tmp_path, unicycle + f'[runtime]\nmode = "{mode}"\n'))
        assert scenario.body.robots(scenario.n) == [1, 2, 3]


def test_robots_follow_scenario_events_in_either_mode() -> None:
    events = Path(__file__).resolve().parents[3] / "scenarios" / "events.toml"
    text = events.read_text() + '\n[body]\nkind = "ros2"\n'
    assert load_dict(tomllib.loads(text), source="events.toml").body.robots(6) == [*range(1, 7)]
    realtime = text + '\n[runtime]\nmode = "realtime"\n'
    s = load_dict(tomllib.loads(realtime), source="events.toml")
    assert s.runtime.mode == "realtime" and len(s.events) == 4


def test_topic_templates_map_a_fleet_s_own_names(tmp_path: Path) -> None:
    # a fleet numbered from 0 (tb3_0, tb3_1, ...) and one named by hand
    s = load(write(tmp_path, '[body]\nkind = "ros2"\npose_topic = "/tb3_{index}/odom"\n'))
    assert [s.body.pose_topic_of(i) for i in (1, 2, 3)] == [
        "/tb3_0/odom",
        "/tb3_1/odom",
        "/tb3_2/odom",
    ]
    named = (
        '[body]\nkind = "ros2"\ncommand_topic = "/{name}/cmd_vel"\nnames = ["ada", "bo", "cy"]\n'
    )
    s = load(write(tmp_path, named))
    assert s.body.command_topic_of(2) == "/bo/cmd_vel"


@pytest.mark.parametrize(
    ("text", "match"),
    [
        (
            'command_topic = "/{name}/cmd_vel"',
            r"bad\.toml: body\.names = \[\]; a topic names \{name\}: give each agent's robot a name",
        ),
        (
            'names = ["ada", "bo"]',
            r"body\.names = \['ada', 'bo'\]; 2 names; expected 3, one per agent",
        ),
        (
            'names = ["ada", "bo", "c-y"]',
            r"body\.names\[2\] = 'c-y'; not one token of a ROS 2 topic name",
        ),
    ],
)
def test_robot_names_are_checked(tmp_path: Path, text: str, match: str) -> None:
    path = write(tmp_path, f'[body]\nkind = "ros2"\n{text}\n')
    path = path.rename(tmp_path / "bad.toml")
    with pytest.raises(ScenarioError, match=match):
        load(path)


def test_a_robot_in_its_own_odometry_frame_is_mapped_to_the_world_and_back(
    tmp_path: Path,
) -> None:
    s = load(
        write(
            tmp_path,
            """
[body]
kind = "ros2"

[[body.transforms]]
agent = 2
frame_id = "tb3_1/odom"
offset_m = [1.0, -2.0]
rotation_rad = 1.5707963267948966
""",
        )
    )
    t = s.body.transform_of(2)
    assert t is not None and s.body.transform_of(1) is None
    assert (s.body.frame_of(1), s.body.frame_of(2)) == ("world", "tb3_1/odom")
    # a quarter turn: the odom frame's x axis is the world's y
    (x, y), yaw = t.to_world([3.0, 0.0], 0.25)
    assert (x, y) == pytest.approx((1.0, 1.0), abs=1e-15) and yaw == pytest.approx(
        0.25 + t.rotation_rad
    )
    assert t.velocity_in_frame([0.0, 0.5]) == pytest.approx([0.5, 0.0], abs=1e-15)
    assert t.velocity_to_world([0.5, 0.0]) == pytest.approx([0.0, 0.5], abs=1e-15)
    assert t.from_world([1.0, 1.0]) == pytest.approx([3.0, 0.0], abs=1e-15)  # as the plant
    (x, y, z), _ = t.to_world([0.0, 0.0, 0.7], 0.0)  # z passes; a 2-D offset has none
    assert (x, y, z) == (1.0, -2.0, 0.7)


def test_a_publisher_s_qos_is_refused_where_dds_would_not_match_it() -> None:
    from formation.body import Qos

    reliable = Qos(reliability="reliable", durability="transient_local")
    assert reliable.refuses("best_effort", "transient_local") == "reliability"
    assert reliable.refuses("reliable", "volatile") == "durability"
    assert reliable.refuses("reliable", "transient_local") is None
    assert reliable.refuses("system_default", "unknown") is None  # not judged
    anything = Qos(reliability="best_effort", durability="volatile")
    assert anything.refuses("best_effort", "volatile") is None
    assert anything.refuses("reliable", "transient_local") is None  # it may offer more
