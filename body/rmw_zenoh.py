"""ROS 2 messages over our own Zenoh session in rmw_zenoh's wire format, with no DDS or rclpy.

What a robot running ``rmw_zenoh_cpp`` puts on its Zenoh router, as its design document and
sources (``liveliness_utils.cpp``, ``attachment_helpers.cpp``) give it (docs/robots.md):

- a topic's key expression ``<domain>/<topic without its outer slashes>/<DDS type name>/<type
  hash>``, e.g. ``0/robot1/cmd_vel/geometry_msgs::msg::dds_::Twist_/RIHS01_9c45…``;
- the payload: the message in CDR with its 4-byte encapsulation header, as rclpy serializes
  it; CDR and the RIHS01 type hashes come from ``rosbags`` (the ``ros2`` extra);
- the attachment: ``"sequence_number"``, int64, ``"source_timestamp"``, int64 [ns],
  ``"source_gid"``, 16 bytes, in Zenoh's own serialization (``zenoh.ext.z_serialize``);
- liveliness tokens, one for the node (``NN``) and one per publisher (``MP``) or
  subscription (``MS``): ``@ros2_lv/<domain>/<zid>/<node id>/<entity id>/<kind>/<enclave>/
  <namespace>/<node>[/<topic>/<type>/<hash>/<qos>]``, names with ``/`` written as ``%``.
"""

from __future__ import annotations

import hashlib
import itertools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from typing import Any

from formation.body import CLOCK_TYPE, Qos

ADMIN_SPACE = "@ros2_lv"
EMPTY = "%"  # an empty namespace or enclave in a liveliness token
GID_BYTES = 16  # RMW_GID_STORAGE_SIZE
# rmw_zenoh writes a QoS field only where it differs from its default profile (reliable,
# transient local, keep last 42, no deadline or lifespan, automatic liveliness), as rmw's enum
_RELIABILITY = {"reliable": "", "best_effort": "2"}
_DURABILITY = {"transient_local": "", "volatile": "2"}
DEFAULT_DEPTH = 42


@cache
def typestore() -> Any:
    """rosbags' store of ROS 2 message types (Kilted: the rclpy of the extra)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_KILTED)


def type_hash(type_name: str) -> str:
    """``geometry_msgs/msg/Twist`` → its RIHS01 type hash (REP 2011)."""
    return str(typestore().hash_rihs01(type_name))


def dds_type_name(type_name: str) -> str:
    """``geometry_msgs/msg/Twist`` → ``geometry_msgs::msg::dds_::Twist_``."""
    package, kind, name = type_name.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def mangle(name: str) -> str:
    """A ROS name inside one chunk of a liveliness token: ``/`` → ``%``."""
    return name.replace("/", EMPTY)


def topic_key(domain: int, topic: str, type_name: str) -> str:
    """The key expression a ROS 2 topic's messages travel on under rmw_zenoh."""
    return f"{domain}/{topic.strip('/')}/{dds_type_name(type_name)}/{type_hash(type_name)}"


def qos_token(qos: Qos) -> str:
    """rmw_zenoh's QoS chunk of a liveliness token, relative to its default profile:
    ``reliability:durability:history,depth:deadline:lifespan:liveliness``."""
    depth = "" if qos.depth == DEFAULT_DEPTH else str(qos.depth)
    return f"{_RELIABILITY[qos.reliability]}:{_DURABILITY[qos.durability]}:,{depth}:,:,:,,"


def node_token(domain: int, zid: str, node_id: int, namespace: str, node: str) -> str:
    node_part = [mangle(namespace) or EMPTY, mangle(node)]
    return "/".join(
        [ADMIN_SPACE, str(domain), zid, str(node_id), str(node_id), "NN", EMPTY, *node_part]
    )


def endpoint_token(
    domain: int,
    zid: str,
    node_id: int,
    entity_id: int,
    kind: str,
    namespace: str,
    node: str,
    topic: str,
    type_name: str,
    qos: Qos,
) -> str:
    """A publisher's (``MP``) or subscription's (``MS``) liveliness token."""
    head = [ADMIN_SPACE, str(domain), zid, str(node_id), str(entity_id), kind, EMPTY]
    names = [mangle(namespace) or EMPTY, mangle(node), mangle(topic)]
    kind_of = [dds_type_name(type_name), type_hash(type_name), qos_token(qos)]
    return "/".join([*head, *names, *kind_of])


def attachment(sequence_number: int, source_timestamp_ns: int, gid: bytes) -> bytes:
    """rmw_zenoh's attachment of a published message, in Zenoh's serialization."""
    from zenoh.ext import Int64, z_serialize

    if len(gid) != GID_BYTES:
        raise ValueError(f"a gid has {GID_BYTES} bytes, got {len(gid)}")
    fields = (
        "sequence_number",
        Int64(sequence_number),
        "source_timestamp",
        Int64(source_timestamp_ns),
        "source_gid",
        gid,
    )
    return bytes(z_serialize(fields).to_bytes())


def parse_attachment(data: bytes) -> tuple[int, int, bytes]:
    """``(sequence_number, source_timestamp_ns, gid)`` of an rmw_zenoh attachment."""
    from zenoh import ZBytes
    from zenoh.ext import Int64, z_deserialize

    types: Any = tuple[str, Int64, str, Int64, str, bytes]
    names = ("sequence_number", "source_timestamp", "source_gid")
    k1, seq, k2, stamp, k3, gid = z_deserialize(types, ZBytes(data))
    if (k1, k2, k3) != names or len(gid) != GID_BYTES:
        raise ValueError(f"not an rmw_zenoh attachment: {(k1, k2, k3)}, gid of {len(gid)} bytes")
    return int(seq), int(stamp), bytes(gid)


def gid_of(key: str) -> bytes:
    """A publisher's gid: 16 bytes fixed by its liveliness token (stable across restarts)."""
    return hashlib.sha256(key.encode()).digest()[:GID_BYTES]


# -- the body's messages, built with rosbags' types ---------------------------------------------
def _time(when_ns: int) -> Any:
    sec, nanosec = divmod(when_ns, 1_000_000_000)
    return typestore().types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)


def _pose(position: list[float], yaw: float) -> Any:
    t = typestore().types
    x, y, z = [*position, 0.0, 0.0, 0.0][:3]
    qz, qw = math.sin(yaw / 2.0), math.cos(yaw / 2.0)
    return t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=x, y=y, z=z),
        orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=qz, w=qw),
    )


def pose_cdr(
    type_name: str,
    position: list[float],
    when_ns: int,
    frame_id: str,
    child_frame_id: str = "",
    yaw: float = 0.0,
) -> bytes:
    """A ``PoseStamped`` or ``Odometry`` (of ``child_frame_id``) at ``position`` [robot m],
    turned ``yaw`` [rad], stamped ``when_ns``, in CDR; its alignment padding is zeros."""
    import numpy as np

    t = typestore().types
    header = t["std_msgs/msg/Header"](stamp=_time(when_ns), frame_id=frame_id)
    if type_name == "geometry_msgs/msg/PoseStamped":
        msg = t[type_name](header=header, pose=_pose(position, yaw))
    else:
        vector = t["geometry_msgs/msg/Vector3"]
        msg = t[type_name](
            header=header,
            child_frame_id=child_frame_id,
            pose=t["geometry_msgs/msg/PoseWithCovariance"](
                pose=_pose(position, yaw), covariance=np.zeros(36)
            ),
            twist=t["geometry_msgs/msg/TwistWithCovariance"](
                twist=t["geometry_msgs/msg/Twist"](
                    linear=vector(x=0.0, y=0.0, z=0.0), angular=vector(x=0.0, y=0.0, z=0.0)
                ),
                covariance=np.zeros(36),
            ),
        )
    return bytes(typestore().serialize_cdr(msg, type_name))


def clock_cdr(when_ns: int) -> bytes:
    """A ``rosgraph_msgs/msg/Clock`` at ``when_ns`` [ns], as CDR."""
    msg = typestore().types[CLOCK_TYPE](clock=_time(when_ns))
    return bytes(typestore().serialize_cdr(msg, CLOCK_TYPE))


def twist_cdr(velocity: list[float], angular_z: float = 0.0) -> bytes:
    """A ``Twist`` whose ``linear`` is ``velocity`` [robot m/s] and ``angular.z`` the turn
    rate [rad/s], in CDR."""
    vector = typestore().types["geometry_msgs/msg/Vector3"]
    x, y, z = [*velocity, 0.0, 0.0, 0.0][:3]
    msg = typestore().types["geometry_msgs/msg/Twist"](
        linear=vector(x=x, y=y, z=z), angular=vector(x=0.0, y=0.0, z=float(angular_z))
    )
    return bytes(typestore().serialize_cdr(msg, "geometry_msgs/msg/Twist"))


def read_pose(type_name: str, data: bytes) -> tuple[list[float], int, float]:
    """A CDR ``PoseStamped`` or ``Odometry`` → (position [robot m], stamp [ns], yaw [rad])."""
    position, when_ns, yaw, _ = read_framed_pose(type_name, data)
    return position, when_ns, yaw


def read_framed_pose(type_name: str, data: bytes) -> tuple[list[float], int, float, str]:
    """:func:`read_pose` and the pose's ``header.frame_id``."""
    from body.ros2 import yaw_of

    msg = typestore().deserialize_cdr(data, type_name)
    pose = msg.pose.pose if type_name == "nav_msgs/msg/Odometry" else msg.pose
    p, q, stamp = pose.position, pose.orientation, msg.header.stamp
    when_ns = int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
    yaw = yaw_of(float(q.x), float(q.y), float(q.z), float(q.w))
    return [float(p.x), float(p.y), float(p.z)], when_ns, yaw, str(msg.header.frame_id)


def read_twist(data: bytes) -> tuple[list[float], float]:
    """A CDR ``Twist`` → its ``linear`` [robot m/s] and ``angular.z`` [rad/s]."""
    msg = typestore().deserialize_cdr(data, "geometry_msgs/msg/Twist")
    return [float(msg.linear.x), float(msg.linear.y), float(msg.linear.z)], float(msg.angular.z)


@dataclass
class RmwZenohNode:
    """A ROS 2 node as rmw_zenoh shows it, on a Zenoh session: its liveliness tokens, and
    publishers whose messages carry rmw_zenoh's attachment."""

    session: Any  # zenoh.Session
    domain: int
    name: str
    namespace: str = "/"

    def __post_init__(self) -> None:
        self.zid = str(self.session.info.zid())
        self._ids = itertools.count(1)
        self.node_id = 0
        self._tokens = [
            self.session.liveliness().declare_token(
                node_token(self.domain, self.zid, self.node_id, self.namespace, self.name)
            )
        ]
        self._entities: list[Any] = []

    def _token(self, kind: str, topic: str, type_name: str, qos: Qos) -> str:
        key = endpoint_token(
            self.domain,
            self.zid,
            self.node_id,
            next(self._ids),
            kind,
            self.namespace,
            self.name,
            topic,
            type_name,
            qos,
        )
        self._tokens.append(self.session.liveliness().declare_token(key))
        return key

    def publisher(self, topic: str, type_name: str, qos: Qos) -> Callable[[bytes], None]:
        """A publish function for CDR payloads on ``topic``."""
        import zenoh

        gid = gid_of(self._token("MP", topic, type_name, qos))
        # reliable: a put waits rather than drop (a stepped plant waits for every command)
        congestion = (
            zenoh.CongestionControl.BLOCK
            if qos.reliability == "reliable"
            else zenoh.CongestionControl.DROP
        )
        pub = self.session.declare_publisher(
            topic_key(self.domain, topic, type_name), congestion_control=congestion
        )
        self._entities.append(pub)
        seq = itertools.count(1)

        def publish(payload: bytes) -> None:
            pub.put(payload, attachment=attachment(next(seq), time.time_ns(), gid))

        return publish

    def subscribe(
        self, topic: str, type_name: str, qos: Qos, on_payload: Callable[[bytes], None]
    ) -> None:
        """``on_payload(cdr)`` for each message on ``topic`` (on Zenoh's thread)."""
        self._token("MS", topic, type_name, qos)
        sub = self.session.declare_subscriber(
            topic_key(self.domain, topic, type_name),
            lambda sample: on_payload(bytes(sample.payload.to_bytes())),
        )
        self._entities.append(sub)

    def close(self) -> None:
        for entity in [*self._entities, *self._tokens]:
            entity.undeclare()
        self._entities, self._tokens = [], []


__all__ = [
    "ADMIN_SPACE",
    "RmwZenohNode",
    "attachment",
    "clock_cdr",
    "dds_type_name",
    "endpoint_token",
    "node_token",
    "parse_attachment",
    "pose_cdr",
    "qos_token",
    "read_framed_pose",
    "read_pose",
    "read_twist",
    "topic_key",
    "twist_cdr",
    "type_hash",
]
