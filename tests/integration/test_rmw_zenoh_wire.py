"""Our rmw_zenoh node against an independent zenoh-python client that follows rmw_zenoh's
documented format by hand (key expression, CDR, attachment, liveliness), two peers on
127.0.0.1. ``rmw_zenoh_cpp`` itself cannot be installed here (docs/robots.md)."""

from __future__ import annotations

import struct
import time
from collections.abc import Callable
from typing import Any

import pytest
import zenoh

from body.rmw_zenoh import RmwZenohNode, pose_cdr, read_pose, twist_cdr
from formation.body import Qos
from shell import session_config
from testkit.zenoh_peer import free_port

pytestmark = pytest.mark.integration
pytest.importorskip("rosbags", reason="the ros2 extra")
TWIST = "geometry_msgs::msg::dds_::Twist_/RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a"
POSE = "geometry_msgs::msg::dds_::PoseStamped_/RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8"


def wait_for(cond: Callable[[], bool], timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def labelled(data: bytes) -> dict[str, Any]:
    """rmw_zenoh's attachment, read by hand: (LEB128 length, UTF-8 label, value) three times."""
    out: dict[str, Any] = {}
    pos = 0
    for _ in range(3):
        n = data[pos]
        label = data[pos + 1 : pos + 1 + n].decode()
        pos += 1 + n
        if label == "source_gid":
            m = data[pos]
            out[label] = data[pos + 1 : pos + 1 + m]
            pos += 1 + m
        else:
            (out[label],) = struct.unpack_from("<q", data, pos)
            pos += 8
    assert pos == len(data)
    return out


@pytest.mark.filterwarnings(
    "ignore:module 'sre_(parse|constants)' is deprecated:DeprecationWarning"
)
def test_an_independent_client_reads_our_command_and_sends_our_pose() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    ours = zenoh.open(session_config("peer", None, endpoint))
    theirs = zenoh.open(session_config("peer", endpoint, None))
    node = RmwZenohNode(ours, 3, "formation_agent_2")
    try:
        # the client subscribes where rmw_zenoh puts /robot2/cmd_vel in domain 3
        got: list[tuple[str, bytes, bytes]] = []
        theirs.declare_subscriber(
            f"3/robot2/cmd_vel/{TWIST}",
            lambda s: got.append(
                (str(s.key_expr), s.payload.to_bytes(), s.attachment and s.attachment.to_bytes())
            ),
        )
        poses: list[tuple[list[float], int, float]] = []
        node.subscribe(
            "/robot2/pose",
            "geometry_msgs/msg/PoseStamped",
            Qos(),
            lambda cdr: poses.append(read_pose("geometry_msgs/msg/PoseStamped", cdr)),
        )
        publish = node.publisher("/robot2/cmd_vel", "geometry_msgs/msg/Twist", Qos())

        def tokens() -> list[str]:
            return sorted(str(r.ok.key_expr) for r in theirs.liveliness().get("@ros2_lv/3/**"))

        wait_for(lambda: len(tokens()) == 3)
        zid = str(ours.info.zid())
        assert tokens() == sorted(
            [
                f"@ros2_lv/3/{zid}/0/0/NN/%/%/formation_agent_2",
                f"@ros2_lv/3/{zid}/0/1/MS/%/%/formation_agent_2/%robot2%pose/{POSE}/:2:,10:,:,:,,",
                f"@ros2_lv/3/{zid}/0/2/MP/%/%/formation_agent_2/%robot2%cmd_vel/{TWIST}/:2:,10:,:,:,,",
            ]
        )
        velocity = [0.1 + 0.2, -1.0 / 3.0]
        sent, deadline = 0, time.monotonic() + 10.0
        while not got:  # until the client's subscription has reached our session
            assert time.monotonic() < deadline, "the client never got our command"
            publish(twist_cdr(velocity))
            sent += 1
            time.sleep(0.01)
        key, payload, att = got[0]
        assert key == f"3/robot2/cmd_vel/{TWIST}"
        # CDR, little endian: the encapsulation header, then linear and angular as 6 doubles
        assert payload[:4] == b"\x00\x01\x00\x00"
        assert struct.unpack("<6d", payload[4:]) == (*velocity, 0.0, 0.0, 0.0, 0.0)
        fields = labelled(att)
        numbers = [labelled(a)["sequence_number"] for _, _, a in got]
        assert numbers == list(range(numbers[0], numbers[0] + len(numbers)))  # one per message
        assert 1 <= numbers[0] <= sent
        assert abs(int(fields["source_timestamp"]) - time.time_ns()) < 10e9
        assert len(fields["source_gid"]) == 16
        # the client sends a pose the way rmw_zenoh would, and our node reads it
        pose = pose_cdr("geometry_msgs/msg/PoseStamped", [1.5, -2.25], 7_000_000_001, "map")
        header = struct.pack("<d", 1.5)
        assert header in pose  # the position is in the bytes as plain doubles
        gid = bytes(range(16))
        att_out = (
            b"\x0fsequence_number" + struct.pack("<q", 1) + b"\x10source_timestamp"
            + struct.pack("<q", time.time_ns()) + b"\x0asource_gid\x10" + gid
        )  # fmt: skip
        theirs.put(f"3/robot2/pose/{POSE}", pose, attachment=att_out)
        wait_for(lambda: bool(poses))
        assert poses == [([1.5, -2.25, 0.0], 7_000_000_001, 0.0)]
    finally:
        node.close()
        theirs.close()
        ours.close()
