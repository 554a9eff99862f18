"""A user's own robots, as a robotics researcher writes them: plain rclpy, not the project's
plant. ``python -m testkit.ros_robot --robot 1=0.5,0.2 --robot 2=...`` runs holonomic robots
that publish ``PoseStamped`` on ``/robot{id}/pose`` at ``--rate-hz`` (wall-clock stamps, frame
``world``) and move by the world-frame velocity of their last ``Twist`` on ``/robot{id}/cmd_vel``,
held until ``--watchdog-s`` passes without one. Faults on demand: ``--stuck I`` ignores its
commands, ``--bad I`` publishes a NaN pose and a 50 m jump every ``BAD_EVERY`` poses once it
is driven, ``--best-effort`` offers the poses best effort, ``--frame I=odom`` stamps robot
``I``'s poses in another frame, ``--yaw I=RAD`` turns robot ``I`` (its commands stay
world-frame).

It prints ``{"ready": true}`` once its publishers exist, and on SIGTERM one JSON line per run:
each robot's commands, zero twists, fastest command [m/s], last command and the watchdog's stops.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import threading
import time
from dataclasses import dataclass, field
from typing import Any

BAD_EVERY = 10  # [poses] a bad robot's NaN, then its jump, in every this many


@dataclass
class Robot:
    ident: int
    position: list[float]
    velocity: list[float] = field(default_factory=lambda: [0.0, 0.0])
    commanded_at: float = 0.0
    commands: int = 0
    zeros: int = 0
    fastest_m_s: float = 0.0
    last: list[float] = field(default_factory=lambda: [0.0, 0.0])
    watchdog_stops: int = 0
    published: int = 0

    def report(self) -> dict[str, Any]:
        return {
            "commands": self.commands,
            "zeros": self.zeros,
            "fastest_m_s": self.fastest_m_s,
            "last": self.last,
            "watchdog_stops": self.watchdog_stops,
            "published": self.published,
        }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser("python -m testkit.ros_robot")
    p.add_argument("--robot", action="append", required=True, help="ID=X,Y: a robot and its start")
    p.add_argument("--rate-hz", type=float, default=50.0)
    p.add_argument("--watchdog-s", type=float, default=0.5)
    p.add_argument("--stuck", type=int, action="append", default=[])
    p.add_argument("--bad", type=int, action="append", default=[])
    p.add_argument("--best-effort", action="store_true")
    p.add_argument("--frame", action="append", default=[], help="ID=FRAME: its poses' frame_id")
    p.add_argument("--yaw", action="append", default=[], help="ID=RAD: its heading (it keeps it)")
    args = p.parse_args(argv)

    import rclpy
    from geometry_msgs.msg import PoseStamped, Twist
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rclpy.signals import SignalHandlerOptions

    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("users_robots")
    lock, stop = threading.Lock(), threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    robots: dict[int, Robot] = {}
    for spec in args.robot:
        ident, _, where = spec.partition("=")
        robots[int(ident)] = Robot(int(ident), [float(c) for c in where.split(",")])
    reliability = ReliabilityPolicy.BEST_EFFORT if args.best_effort else ReliabilityPolicy.RELIABLE
    pose_qos = QoSProfile(depth=10, reliability=reliability)

    def on_twist(robot: Robot, msg: Any) -> None:
        v = [float(msg.linear.x), float(msg.linear.y)]
        with lock:
            robot.commands += 1
            robot.zeros += v == [0.0, 0.0]
            robot.fastest_m_s = max(robot.fastest_m_s, math.hypot(*v))
            robot.last, robot.commanded_at = v, time.monotonic()
            if robot.ident not in args.stuck:
                robot.velocity = v

    publishers = {}
    for i, robot in robots.items():
        publishers[i] = node.create_publisher(PoseStamped, f"/robot{i}/pose", pose_qos)
        node.create_subscription(
            Twist, f"/robot{i}/cmd_vel", lambda msg, r=robot: on_twist(r, msg), 10
        )
    period_s = 1.0 / args.rate_hz
    frames = dict(spec.split("=", 1) for spec in args.frame)
    yaws = {int(i): float(rad) for i, _, rad in (spec.partition("=") for spec in args.yaw)}

    def tick() -> None:
        now = time.monotonic()
        for i, robot in robots.items():
            with lock:
                moving = robot.velocity != [0.0, 0.0]
                if moving and now - robot.commanded_at > args.watchdog_s:
                    robot.velocity = [0.0, 0.0]
                    robot.watchdog_stops += 1
                robot.position = [
                    c + v * period_s for c, v in zip(robot.position, robot.velocity, strict=True)
                ]
                robot.published += 1
                where = list(robot.position)
            bad = i in args.bad and robot.commands > 0  # once driven: its start is good
            if bad and robot.published % BAD_EVERY == BAD_EVERY - 2:
                where = [math.nan, where[1]]
            elif bad and robot.published % BAD_EVERY == BAD_EVERY - 1:
                where = [where[0] + 50.0, where[1]]
            msg = PoseStamped()
            msg.header.frame_id = frames.get(str(i), "world")
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(time.time_ns(), 1_000_000_000)
            msg.pose.position.x, msg.pose.position.y = where
            yaw = yaws.get(i, 0.0)
            msg.pose.orientation.z, msg.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
            publishers[i].publish(msg)

    node.create_timer(period_s, tick)
    print(json.dumps({"ready": True}), flush=True)
    while not stop.is_set():
        rclpy.spin_once(node, timeout_sec=0.1)
    with lock:
        print(json.dumps({str(i): r.report() for i, r in robots.items()}), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
