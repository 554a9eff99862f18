"""A ROS 2 node beside the bus: rclpy on its own context and thread, and the body's messages.

rclpy is the optional extra ``ros2`` (formation/body.py); nothing here imports it before
:func:`open_ros_node`, so the services work without it, and a scenario that needs it is
refused by :func:`require_ros2` with the extra to install. The node spins on a thread of
its own (its callbacks run there), on a context of its own: rclpy's default context would
install its own SIGINT and SIGTERM handlers over the service's (shell/serving.py).

An epoch travels in a pose's ``header.stamp`` as the sim time ``k T`` (docs/robots.md):
the stepped plant stamps the pose it publishes after epoch ``k``'s commands with
``k + 1``, so an agent in lockstep knows which pose ends which epoch.
"""

from __future__ import annotations

import logging
import math
import os
import sys
import threading
from collections.abc import Callable, Sequence
from typing import Any

from formation.body import Body, Qos
from formation.errors import Ros2Missing

log = logging.getLogger("ros2")
NS_PER_S = 1_000_000_000
SPIN_WAKE_S = 0.1  # [s] how often the node's thread looks whether it is to stop


def require_ros2(
    who: str, pose_type: str = "geometry_msgs/msg/PoseStamped", kind: str = "ros2"
) -> None:
    """Import what a body of ``kind`` uses, or raise :class:`Ros2Missing`: rclpy and the
    message packages (``ros2``), and rosbags (both: the recorded traffic's CDR, rmw_zenoh's
    format)."""
    package = pose_type.split("/", 1)[0]
    modules: tuple[str, ...] = ("rosbags.typesys",)
    if kind != "rmw_zenoh":
        modules = ("rclpy", "geometry_msgs.msg", f"{package}.msg", *modules)
    for module in modules:
        try:
            __import__(module)
        except ImportError:
            raise Ros2Missing(who, module.split(".", 1)[0]) from None


def message_class(type_name: str) -> Any:
    """``"geometry_msgs/msg/Twist"`` → the rclpy message class."""
    package, _, name = type_name.split("/")
    module = __import__(f"{package}.msg", fromlist=[name])
    return getattr(module, name)


def qos_profile(qos: Qos) -> Any:
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=qos.depth,
        reliability=ReliabilityPolicy.RELIABLE
        if qos.reliability == "reliable"
        else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL
        if qos.durability == "transient_local"
        else DurabilityPolicy.VOLATILE,
    )


def qos_words(qos: Qos) -> str:
    """A scenario's QoS in words, as :func:`profile_words` writes rclpy's: the policies a
    publisher and a subscription are matched on (discovery does not carry the depth)."""
    return f"reliability {qos.reliability}, durability {qos.durability}"


def profile_words(profile: Any) -> str:
    """An rclpy ``QoSProfile`` in words: reliability, durability."""
    return (
        f"reliability {policy_name(profile.reliability)}, "
        f"durability {policy_name(profile.durability)}"
    )


def policy_name(policy: Any) -> str:
    """An rclpy QoS policy or policy kind by its short name (``best_effort``, ``reliability``)."""
    return str(getattr(policy, "name", policy)).lower().removeprefix("rmw_qos_policy_")


def stamp_ns(msg: Any) -> int:
    """A stamped message's ``header.stamp`` in integer nanoseconds."""
    stamp = msg.header.stamp
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def pose_position(msg: Any) -> tuple[float, float, float]:
    """The position of a ``PoseStamped`` or an ``Odometry`` [robot m]."""
    pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
    p = pose.position
    return float(p.x), float(p.y), float(p.z)


def pose_message(
    cls: Any, position: Sequence[float], when_ns: int, frame_id: str, yaw: float = 0.0
) -> Any:
    """A ``PoseStamped`` or ``Odometry`` at ``position`` (2 or 3 coordinates) [robot m],
    turned ``yaw`` [rad] about z."""
    msg = cls()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(when_ns, NS_PER_S)
    msg.header.frame_id = frame_id
    pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
    xyz = [*position, 0.0, 0.0, 0.0][:3]
    pose.position.x, pose.position.y, pose.position.z = (float(c) for c in xyz)
    pose.orientation.z, pose.orientation.w = math.sin(yaw / 2.0), math.cos(yaw / 2.0)
    return msg


def pose_yaw(msg: Any) -> float:
    """The heading about z of a ``PoseStamped``'s or an ``Odometry``'s orientation [rad]."""
    pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
    q = pose.orientation
    return yaw_of(float(q.x), float(q.y), float(q.z), float(q.w))


def yaw_of(x: float, y: float, z: float, w: float) -> float:
    """The yaw of a unit quaternion [rad]."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def twist_message(cls: Any, velocity: Sequence[float], angular_z: float = 0.0) -> Any:
    """A ``Twist``: ``linear`` is ``velocity`` (2 or 3 coordinates) [robot m/s], ``angular.z``
    the turn rate [rad/s] (a unicycle: ``linear.x`` and ``angular.z``)."""
    msg = cls()
    xyz = [*velocity, 0.0, 0.0, 0.0][:3]
    msg.linear.x, msg.linear.y, msg.linear.z = (float(c) for c in xyz)
    msg.angular.z = float(angular_z)
    return msg


def twist_velocity(msg: Any, dimension: int) -> list[float]:
    return [float(msg.linear.x), float(msg.linear.y), float(msg.linear.z)][:dimension]


class RosNode:
    """An rclpy node on its own context, spinning on its own thread until :meth:`close`."""

    def __init__(self, name: str, body: Body) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        self.body = body
        self.context = Context()
        rclpy.init(context=self.context, domain_id=body.domain_id)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.pose_class = message_class(body.pose_type)
        self.command_class = message_class(body.command_type)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, name=f"ros2-{name}", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        # Our own loop, stopped by our flag: rclpy's Executor.shutdown() destroys the guard
        # condition a spinning wait may still hold, and an agent hung at its exit (1 run in 5).
        while not self._stop.is_set() and self.context.ok():
            self.executor.spin_once(timeout_sec=SPIN_WAKE_S)

    def subscribe(
        self,
        topic: str,
        cls: Any,
        qos: Qos,
        callback: Callable[[Any], None],
        on_incompatible: Callable[[Any], None] | None = None,
    ) -> Any:
        """A subscription; ``on_incompatible`` gets rclpy's requested-incompatible-QoS event."""
        from rclpy.event_handler import SubscriptionEventCallbacks

        events = SubscriptionEventCallbacks(incompatible_qos=on_incompatible)
        return self.node.create_subscription(
            cls, topic, callback, qos_profile(qos), event_callbacks=events
        )

    def publisher(self, topic: str, cls: Any, qos: Qos) -> Any:
        return self.node.create_publisher(cls, topic, qos_profile(qos))

    def close(self, timeout_s: float = 5.0, destroy: bool = True) -> None:
        """The spinning thread first, then the executor, the node (``destroy``) and the
        context; given up on after ``timeout_s`` (logged).

        A process that ends next passes ``destroy=False`` and ends by :func:`exit_process`:
        rclpy's ``destroy_node`` can block inside Fast DDS holding the GIL, which freezes every
        thread of the process, a timeout's too (an agent hung at its exit, 1 run in 25). The
        context's shutdown destroys its nodes as well, so it is left to the process's end too.
        """
        self._stop.set()
        self._thread.join(timeout=timeout_s)

        def teardown() -> None:
            self.executor.shutdown(timeout_sec=1.0)
            if destroy:
                self.node.destroy_node()
                self.context.try_shutdown()

        done = threading.Thread(target=teardown, name="ros2-close", daemon=True)
        done.start()
        done.join(timeout=timeout_s)
        if done.is_alive() or self._thread.is_alive():
            log.warning("the ROS 2 node %s did not close in %g s", self.node.get_name(), timeout_s)


_opened: list[RosNode] = []  # every node of this process, kept until it ends


def exit_process(code: int) -> None:
    """End the process with ``code``: at once, past Python's finalisation, if it opened a ROS 2
    node (finalising one runs rclpy's teardown, see :meth:`RosNode.close`), else as usual."""
    if not _opened:
        sys.exit(code)
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def open_ros_node(name: str, body: Body) -> RosNode:
    """A :class:`RosNode` named ``name`` (a ROS 2 node name: letters, digits, underscores)."""
    require_ros2(name, body.pose_type)
    node = RosNode(name, body)
    _opened.append(node)
    return node


__all__ = [
    "NS_PER_S",
    "RosNode",
    "exit_process",
    "message_class",
    "open_ros_node",
    "policy_name",
    "pose_message",
    "pose_position",
    "pose_yaw",
    "profile_words",
    "qos_profile",
    "qos_words",
    "require_ros2",
    "stamp_ns",
    "twist_message",
    "twist_velocity",
    "yaw_of",
]
