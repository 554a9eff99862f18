"""rmw_zenoh's wire format, computed with rosbags, against what rclpy itself produces."""

from __future__ import annotations

import os
import struct
import zlib
from collections.abc import Iterator

import pytest

from body.rmw_zenoh import (
    attachment,
    clock_cdr,
    dds_type_name,
    endpoint_token,
    node_token,
    parse_attachment,
    pose_cdr,
    qos_token,
    read_pose,
    read_twist,
    topic_key,
    twist_cdr,
    type_hash,
)
from formation.body import Qos

pytest.importorskip("rosbags", reason="the ros2 extra")
TYPES = ("geometry_msgs/msg/Twist", "geometry_msgs/msg/PoseStamped", "nav_msgs/msg/Odometry")
ODD = [0.1 + 0.2, -1.0 / 3.0, 5e-324]  # floats whose every bit matters
# rosidl's type support imports lark-parser 0.12, which imports the deprecated sre_parse
rclpy_warnings = pytest.mark.filterwarnings(
    "ignore:module 'sre_(parse|constants)' is deprecated:DeprecationWarning"
)


@rclpy_warnings
@pytest.mark.parametrize("type_name", TYPES[1:])
def test_a_pose_in_cdr_is_the_bytes_rclpy_serializes(type_name: str) -> None:
    pytest.importorskip("rclpy")
    from rclpy.serialization import serialize_message

    from body.ros2 import message_class, pose_message

    # Frame names of 3 and 11 letters: CDR then needs no alignment padding, which rclpy's
    # serializer leaves as whatever was in its buffer (rosbags writes zeros).
    when_ns = 1_733_000_000_123_456_789
    ours = pose_cdr(type_name, ODD, when_ns, "map", child_frame_id="base_link_1", yaw=-2.0)
    msg = pose_message(message_class(type_name), ODD, when_ns, "map", yaw=-2.0)
    if hasattr(msg, "child_frame_id"):
        msg.child_frame_id = "base_link_1"
    assert ours == serialize_message(msg)
    position, stamp, yaw = read_pose(type_name, ours)
    assert (position, stamp) == (ODD, when_ns)
    assert abs(yaw + 2.0) < 1e-15


@rclpy_warnings
def test_a_twist_in_cdr_is_the_bytes_rclpy_serializes() -> None:
    pytest.importorskip("rclpy")
    from geometry_msgs.msg import Twist
    from rclpy.serialization import serialize_message

    from body.ros2 import twist_message

    assert twist_cdr(ODD[:2]) == serialize_message(twist_message(Twist, ODD[:2]))
    assert twist_cdr([0.1], -1.5) == serialize_message(twist_message(Twist, [0.1], -1.5))
    assert read_twist(twist_cdr(ODD, 2.5)) == (ODD, 2.5)


@rclpy_warnings
def test_a_clock_in_cdr_is_the_bytes_rclpy_serializes() -> None:
    pytest.importorskip("rclpy")
    from rclpy.serialization import serialize_message
    from rosgraph_msgs.msg import Clock

    msg = Clock()
    msg.clock.sec, msg.clock.nanosec = 1_733_000_000, 123_456_789
    assert clock_cdr(1_733_000_000_123_456_789) == serialize_message(msg)


@pytest.fixture
def rclpy_node(monkeypatch: pytest.MonkeyPatch, tmp_path: object) -> Iterator[object]:
    """An rclpy node on a context of its own, DDS discovery on this host only."""
    rclpy = pytest.importorskip("rclpy")
    from rclpy.context import Context

    domain = 1 + zlib.crc32(f"rmw_zenoh/{os.getpid()}".encode()) % 100  # DDS ports < 32768
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    monkeypatch.setenv("ROS_LOG_DIR", str(tmp_path))
    context = Context()
    rclpy.init(context=context, domain_id=domain)
    node = rclpy.create_node("type_hashes", context=context)
    try:
        yield node
    finally:
        node.destroy_node()
        context.try_shutdown()


@rclpy_warnings
def test_the_type_hashes_are_those_rclpy_announces(rclpy_node: object) -> None:
    from body.ros2 import message_class

    node: object = rclpy_node
    for k, type_name in enumerate(TYPES):
        topic = f"/hash{k}"
        node.create_publisher(message_class(type_name), topic, 1)  # type: ignore[attr-defined]
        (info,) = node.get_publishers_info_by_topic(topic)  # type: ignore[attr-defined]
        assert type_hash(type_name) == str(info.topic_type_hash), type_name
        assert info.topic_type == type_name


def test_keys_and_tokens_are_rmw_zenohs() -> None:
    twist = "geometry_msgs/msg/Twist"
    assert dds_type_name(twist) == "geometry_msgs::msg::dds_::Twist_"
    hash_ = "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a"
    assert type_hash(twist) == hash_
    assert topic_key(7, "/robot3/cmd_vel/", twist) == (
        f"7/robot3/cmd_vel/geometry_msgs::msg::dds_::Twist_/{hash_}"
    )
    # rmw_zenoh's default profile is reliable, transient local, keep last 42: empty fields
    assert qos_token(Qos(durability="transient_local", depth=42)) == "::,:,:,:,,"
    assert qos_token(Qos()) == ":2:,10:,:,:,,"
    assert qos_token(Qos(reliability="best_effort", depth=1)) == "2:2:,1:,:,:,,"
    assert node_token(0, "abc", 0, "/", "formation_agent_3") == (
        "@ros2_lv/0/abc/0/0/NN/%/%/formation_agent_3"
    )
    assert endpoint_token(0, "abc", 0, 2, "MP", "/", "n", "/robot3/cmd_vel", twist, Qos()) == (
        f"@ros2_lv/0/abc/0/2/MP/%/%/n/%robot3%cmd_vel/geometry_msgs::msg::dds_::Twist_/{hash_}/"
        ":2:,10:,:,:,,"
    )


def test_the_attachment_is_zenohs_serialization_of_the_three_labelled_fields() -> None:
    gid = bytes(range(16))
    data = attachment(42, 1_700_000_000_000_000_000, gid)

    def label(text: str) -> bytes:  # a string: its length (one LEB128 byte here), then UTF-8
        return bytes([len(text)]) + text.encode()

    assert data == (
        label("sequence_number")
        + struct.pack("<q", 42)
        + label("source_timestamp")
        + struct.pack("<q", 1_700_000_000_000_000_000)
        + label("source_gid")
        + bytes([16])
        + gid
    )
    assert parse_attachment(data) == (42, 1_700_000_000_000_000_000, gid)
    with pytest.raises(ValueError, match="a gid has 16 bytes, got 3"):
        attachment(1, 1, b"abc")
