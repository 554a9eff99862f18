"""The link to ROS 2 robots, whichever way it goes: rclpy over DDS, or rmw_zenoh's format on
a Zenoh session (``[body] kind``, formation/body.py). The agents and the plant talk to a
:class:`BodyLink`; positions and velocities are plain lists [robot m, robot m/s], and a
pose's stamp is in integer nanoseconds.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

from body.rmw_zenoh import (
    RmwZenohNode,
    clock_cdr,
    pose_cdr,
    read_framed_pose,
    read_twist,
    twist_cdr,
)
from body.ros2 import (
    NS_PER_S,
    RosNode,
    message_class,
    open_ros_node,
    policy_name,
    pose_message,
    pose_position,
    pose_yaw,
    profile_words,
    qos_words,
    stamp_ns,
    twist_message,
    twist_velocity,
)
from formation.body import CLOCK_QOS, CLOCK_TOPIC, CLOCK_TYPE, Body

# position [robot m], stamp [ns], yaw [rad], header.frame_id
OnPose = Callable[[list[float], int, float, str], None]
OnCommand = Callable[[list[float], float], None]  # linear [robot m/s], angular.z [rad/s]
# A publisher whose QoS cannot match the subscription: (offered, requested, policy) in words
OnMismatch = Callable[[str, str, str], None]


class Endpoint(Protocol):
    def matched(self) -> bool:
        """Whether the other end is there (a publisher: a subscriber; a subscription: a publisher)."""
        ...


class PosePublisher(Endpoint, Protocol):
    def publish(self, position: list[float], stamp_ns: int, yaw: float) -> None: ...


class CommandPublisher(Endpoint, Protocol):
    def publish(self, velocity: list[float], angular_z: float) -> None: ...
    def delivered(self, timeout_s: float) -> bool:
        """Whether every command published reached its subscribers (reliable) in ``timeout_s``."""
        ...


class ClockPublisher(Protocol):
    def publish(self, when_ns: int) -> None:
        """The time ``when_ns`` [ns] on ``/clock``, for nodes with ``use_sim_time``."""
        ...


class BodyLink(Protocol):
    """Robots' poses and commands on their topics (a ROS 2 node's, on one transport)."""

    def poses(
        self, topic: str, on_pose: OnPose, on_mismatch: OnMismatch | None = None
    ) -> Endpoint: ...
    def commands(self, topic: str, on_command: OnCommand) -> Endpoint: ...
    def refused_by(self, topic: str) -> tuple[str, str, str] | None:
        """Whether the publishers on ``topic``, as the ROS graph shows them, all have a QoS that
        cannot match the pose subscription: (offered, requested, policy) in words, else None."""
        ...

    def pose_publisher(self, topic: str, frame_id: str | None = None) -> PosePublisher:
        """Poses on ``topic`` stamped ``frame_id`` (None: ``body.frame_id``)."""
        ...

    def command_publisher(self, topic: str) -> CommandPublisher: ...
    def clock_publisher(self) -> ClockPublisher: ...
    def close(self) -> None: ...


class _RosEndpoint:
    def __init__(self, entity: Any, publish: Callable[..., None] | None = None) -> None:
        self.entity, self._publish = entity, publish

    def matched(self) -> bool:
        count = (
            getattr(self.entity, "get_subscription_count", None) or self.entity.get_publisher_count
        )
        return bool(count() > 0)

    def publish(self, *args: Any) -> None:
        assert self._publish is not None
        self._publish(*args)

    def delivered(self, timeout_s: float) -> bool:
        from rclpy.duration import Duration

        return bool(self.entity.wait_for_all_acked(Duration(nanoseconds=int(timeout_s * 1e9))))


class RclpyLink:
    """Over DDS, through an rclpy node (:class:`body.ros2.RosNode`)."""

    def __init__(self, name: str, body: Body) -> None:
        self.body = body
        self.node: RosNode = open_ros_node(name, body)

    def poses(self, topic: str, on_pose: OnPose, on_mismatch: OnMismatch | None = None) -> Endpoint:
        requested = qos_words(self.body.pose_qos)

        def incompatible(info: Any) -> None:  # rclpy's QoS event, on the node's thread
            if on_mismatch is not None:
                policy = policy_name(info.last_policy_kind)
                on_mismatch(self._offered(topic), requested, policy)

        sub = self.node.subscribe(
            topic,
            self.node.pose_class,
            self.body.pose_qos,
            lambda msg: on_pose(
                list(pose_position(msg)), stamp_ns(msg), pose_yaw(msg), msg.header.frame_id
            ),
            on_incompatible=incompatible,
        )
        return _RosEndpoint(sub)

    def refused_by(self, topic: str) -> tuple[str, str, str] | None:
        # the graph, should the RMW raise no incompatible-QoS event; on rmw_zenoh_cpp every
        # pair of QoS profiles is carried, so none is refused
        from rclpy.utilities import get_rmw_implementation_identifier

        if get_rmw_implementation_identifier() == "rmw_zenoh_cpp":
            return None
        requested = self.body.pose_qos
        policies = [
            requested.refuses(policy_name(p.reliability), policy_name(p.durability))
            for p in (
                info.qos_profile for info in self.node.node.get_publishers_info_by_topic(topic)
            )
        ]
        if not policies or None in policies:  # none, or one a pose can come from
            return None
        return self._offered(topic), qos_words(requested), str(policies[0])

    def _offered(self, topic: str) -> str:
        """The QoS of the publishers on ``topic``, in words (rclpy's graph)."""
        infos = self.node.node.get_publishers_info_by_topic(topic)
        return "; ".join(profile_words(info.qos_profile) for info in infos) or "(no publisher)"

    def commands(self, topic: str, on_command: OnCommand) -> Endpoint:
        sub = self.node.subscribe(
            topic,
            self.node.command_class,
            self.body.command_qos,
            lambda msg: on_command(twist_velocity(msg, 3), float(msg.angular.z)),
        )
        return _RosEndpoint(sub)

    def pose_publisher(self, topic: str, frame_id: str | None = None) -> PosePublisher:
        pub = self.node.publisher(topic, self.node.pose_class, self.body.pose_qos)
        cls, frame = self.node.pose_class, frame_id or self.body.frame_id
        return _RosEndpoint(
            pub, lambda p, when, yaw: pub.publish(pose_message(cls, p, when, frame, yaw))
        )

    def command_publisher(self, topic: str) -> CommandPublisher:
        pub = self.node.publisher(topic, self.node.command_class, self.body.command_qos)
        cls = self.node.command_class
        return _RosEndpoint(pub, lambda u, w: pub.publish(twist_message(cls, u, w)))

    def clock_publisher(self) -> ClockPublisher:
        cls = message_class(CLOCK_TYPE)
        pub = self.node.publisher(CLOCK_TOPIC, cls, CLOCK_QOS)

        def publish(when_ns: int) -> None:
            msg = cls()
            msg.clock.sec, msg.clock.nanosec = divmod(when_ns, NS_PER_S)
            pub.publish(msg)

        return _RosEndpoint(pub, publish)

    def close(self) -> None:
        self.node.close(destroy=False)  # the process ends next, by body.exit_process


class _ZenohEndpoint:
    def __init__(self, publish: Callable[..., None] | None = None) -> None:
        self._publish = publish

    def matched(self) -> bool:
        # Zenoh routes a put to the subscribers its router knows; the router learns a
        # subscriber before that peer's later puts (its pose), so the first command after the
        # first pose reaches the plant
        return True

    def publish(self, *args: Any) -> None:
        assert self._publish is not None
        self._publish(*args)

    def delivered(self, timeout_s: float) -> bool:
        return True  # a reliable put has left when it returns


class ZenohLink:
    """rmw_zenoh's wire format on a Zenoh session (:mod:`body.rmw_zenoh`), in domain
    ``body.domain_id`` (default 0)."""

    def __init__(self, session: Any, name: str, body: Body) -> None:
        self.body = body
        self.node = RmwZenohNode(session, body.domain_id or 0, name)

    def poses(self, topic: str, on_pose: OnPose, on_mismatch: OnMismatch | None = None) -> Endpoint:
        # no QoS events here: rmw_zenoh matches every publisher with every subscription
        kind = self.body.pose_type
        self.node.subscribe(
            topic, kind, self.body.pose_qos, lambda b: on_pose(*read_framed_pose(kind, b))
        )
        return _ZenohEndpoint()

    def refused_by(self, topic: str) -> tuple[str, str, str] | None:
        return None  # Zenoh carries a pose whatever QoS either end asks for

    def commands(self, topic: str, on_command: OnCommand) -> Endpoint:
        twist = self.body.command_type
        self.node.subscribe(
            topic, twist, self.body.command_qos, lambda b: on_command(*read_twist(b))
        )
        return _ZenohEndpoint()

    def pose_publisher(self, topic: str, frame_id: str | None = None) -> PosePublisher:
        kind, frame = self.body.pose_type, frame_id or self.body.frame_id
        put = self.node.publisher(topic, kind, self.body.pose_qos)
        return _ZenohEndpoint(lambda p, when, yaw: put(pose_cdr(kind, p, when, frame, yaw=yaw)))

    def command_publisher(self, topic: str) -> CommandPublisher:
        put = self.node.publisher(topic, self.body.command_type, self.body.command_qos)
        return _ZenohEndpoint(lambda u, w: put(twist_cdr(u, w)))

    def clock_publisher(self) -> ClockPublisher:
        put = self.node.publisher(CLOCK_TOPIC, CLOCK_TYPE, CLOCK_QOS)
        return _ZenohEndpoint(lambda when: put(clock_cdr(when)))

    def close(self) -> None:
        self.node.close()


def open_body_link(name: str, body: Body, session: Any = None) -> BodyLink:
    """The link of ``body.kind``: ``ros2`` opens an rclpy node named ``name``; ``rmw_zenoh``
    uses ``session`` (a ``zenoh.Session``)."""
    if body.kind == "rmw_zenoh":
        if session is None:
            raise ValueError("an rmw_zenoh body needs a Zenoh session")
        return ZenohLink(session, name, body)
    return RclpyLink(name, body)


__all__ = [
    "BodyLink",
    "ClockPublisher",
    "CommandPublisher",
    "Endpoint",
    "OnMismatch",
    "PosePublisher",
    "open_body_link",
]
