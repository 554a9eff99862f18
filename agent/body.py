"""An agent's body on ROS 2: its state from the robot's pose, its command as a ``Twist``.

With ``[body] kind = "ros2"`` (formation/body.py) the agent process is also a ROS 2 node
(:mod:`body.ros2`). After each step it sends the velocity that takes its body from
``x[k]`` to the ``x[k+1]`` it computed, ``u = (x[k+1] − x[k]) / T`` [m/s], and then takes
``x[k+1]`` from the robot's pose (docs/robots.md):

- lockstep: the pose stamped with epoch ``k + 1`` (the stepped plant publishes it once every
  command of epoch ``k`` is in);
- realtime: the newest pose, as a robot publishes it.

A unicycle publishes its axle's centre and heading; its state is the look-ahead point, and
the agent runs the robot's inner loop: at each pose it sends the ``linear.x``, ``angular.z``
(:func:`agent.control.unicycle_twist`) that move the look-ahead point at the epoch's
velocity. In lockstep that is one sub-step of the simulator's loop per pose, to the bit
(:mod:`agent.steering`).

A pose that is not finite, or further from the last one than the body can move in an epoch,
is counted and not used; no usable pose for ``pose_timeout_s`` and the body is lost.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np
import numpy.typing as npt

from agent.control import unicycle_twist
from agent.steering import InnerLoop, confirmed_pose, pose_point
from body import NS_PER_S, open_body_link, pose_cdr, twist_cdr
from formation.errors import BodyLost
from formation.scenario import Scenario

log = logging.getLogger("agent.body")
FIRST_POSE_S = 60.0  # [s] for the first pose: the plant or the robot may still be starting
Array = npt.NDArray[np.float64]


@dataclass
class _Pose:
    stamp_ns: int
    position: list[float]  # the state: the robot's position, a unicycle's look-ahead point [m]
    arrived_s: float  # time.monotonic() when it came
    heading: float = 0.0  # [rad]
    robot_xyz: tuple[float, ...] = ()  # as published [robot m]
    centre: list[float] = field(default_factory=list)  # a unicycle's axle centre [m]


class RobotBodies:
    """The ROS 2 bodies of a process's agents ``ids``: pose subscriptions, command publishers."""

    def __init__(self, scenario: Scenario, ids: list[int], name: str, session: Any = None) -> None:
        self.scenario, self.body = scenario, scenario.body
        self.ids = [i for i in ids if self.body.has_robot(i)]
        self.period_ns = round(scenario.control.period_s * NS_PER_S)
        # rclpy's node (ros2), or rmw_zenoh's format on the service's own session (rmw_zenoh)
        self.link = open_body_link(name.replace("-", "_"), self.body, session)
        self._cond = threading.Condition()
        self._poses: dict[int, _Pose] = {}
        self.counts = {"poses": 0, "commands": 0, "bad_poses": 0, "jumps": 0}
        self.last_command: dict[int, list[float]] = {}
        self._used: dict[int, float] = {}  # the arrival of the pose each robot was last placed by
        self.latency_s: list[float] = []  # pose in → command out, per command [s]
        # How far a body may move in one epoch before a pose counts as a jump [m]: the
        # shape's size, twice over (a consensus step is a fraction of the errors).
        span = float(np.ptp(scenario.offsets, axis=0).max()) if scenario.n > 1 else 1.0
        self.max_jump_m = 2.0 * (span + 2.0 * scenario.initial.spread_m) + 1.0
        self.unicycle = scenario.control.dynamics == "unicycle"
        self.limits = scenario.control.unicycle.limits
        self._u: dict[int, Array] = {}  # a unicycle's look-ahead velocity this epoch [m/s]
        # lockstep unicycles: each robot's inner loop of this epoch, and its x[k], θ[k]
        self.stepped = self.unicycle and scenario.runtime.mode != "realtime"
        self._loops: dict[int, InnerLoop] = {}
        self._start: dict[int, tuple[list[float], float]] = {}
        self.counts["yaw_taken"] = 0
        self._twists: dict[int, tuple[list[float], float]] = {}  # last sent [robot m/s, rad/s]
        self._subscriptions = [
            self.link.poses(self.body.pose_topic_of(i), partial(self._on_pose, i)) for i in self.ids
        ]
        self._publishers = {
            i: self.link.command_publisher(self.body.command_topic_of(i)) for i in self.ids
        }

    def _on_pose(self, agent: int, xyz: list[float], stamp: int, yaw: float) -> None:
        """On the link's thread: keep the newest usable pose of ``agent`` (a unicycle's: and
        send its next inner-loop command)."""
        d, scale = self.scenario.dimension, self.body.scale
        centre = position = [c / scale for c in xyz[:d]]
        if self.unicycle:  # the look-ahead point of the axle's centre
            position = pose_point(centre, yaw, self.limits[2])
        with self._cond:
            self.counts["poses"] += 1
            if not all(math.isfinite(c) for c in [*position, yaw]):
                self.counts["bad_poses"] += 1
                return
            last = self._poses.get(agent)
            if last is not None and math.dist(last.position, position) > self.max_jump_m:
                self.counts["jumps"] += 1
                return
            self._poses[agent] = _Pose(stamp, position, time.monotonic(), yaw, tuple(xyz), centre)
            self._cond.notify_all()
            if self.unicycle and agent in self._u:
                self._steer(agent, yaw)
            if agent in self._loops:
                self._answer(agent, self._loops[agent], centre, yaw, stamp)

    def _answer(
        self, agent: int, loop: InnerLoop, centre: list[float], yaw: float, at: int
    ) -> None:
        """Lockstep: a unicycle's pose of a sub-step → its next twist (none at the epoch's end)."""
        twist = loop.on_pose(centre, yaw, at)
        if twist is not None:
            self._send(agent, *twist)

    def _steer(self, agent: int, yaw: float) -> None:
        """A unicycle's inner loop: the speeds that move its look-ahead point at this epoch's
        velocity from heading ``yaw`` (clipped to its limits)."""
        v, w, _ = unicycle_twist(np.array([yaw]), self._u[agent][None, :], self.limits)
        self._send(agent, float(v[0]), float(w[0]))

    def _send(self, agent: int, v: float, w: float) -> None:
        """A unicycle's twist: ``linear.x`` [m/s] (times ``scale``), ``angular.z`` [rad/s]."""
        twist = ([v * self.body.scale, 0.0], w)
        self._publishers[agent].publish(*twist)
        self._twists[agent] = twist

    def settle(
        self, expected: dict[int, tuple[list[float], float]]
    ) -> tuple[dict[int, list[float]], dict[int, float]]:
        """Lockstep unicycles, as they start: each robot's ``x[k]`` [m] and ``θ[k]`` [rad] from
        its newest pose, ``expected`` where it confirms them (agent.steering.confirmed_pose)."""
        with self._cond:
            for i in self.ids:
                pose = self._poses[i]
                p, heading, agrees = confirmed_pose(
                    expected[i], pose.centre, pose.heading, self.limits[2]
                )
                if not agrees:  # its pose then, not the state expected
                    self.counts["yaw_taken"] += 1
                    start, turned = expected[i]
                    log.warning(
                        "agent %d: its robot starts at %s heading %r (its pose), not at %s "
                        "heading %r",
                        i,
                        p,
                        heading,
                        start,
                        turned,
                    )
                self._start[i] = (p, heading)
            return self._placed()

    def _placed(self) -> tuple[dict[int, list[float]], dict[int, float]]:
        """Each robot's ``x[k]`` [m] and ``θ[k]`` [rad] its inner loop starts from."""
        positions = {i: p for i, (p, _) in self._start.items()}
        return positions, {i: heading for i, (_, heading) in self._start.items()}

    def steer(self, epoch: int, velocities: dict[int, list[float]]) -> None:
        """Lockstep unicycles: drive each robot's look-ahead point at its velocity [m/s] over
        epoch ``epoch``, a twist per pose (:class:`agent.steering.InnerLoop`)."""
        period_s = self.scenario.control.period_s
        with self._cond:
            for i, u in velocities.items():
                p, heading = self._start[i]
                loop = InnerLoop(
                    np.array([u], dtype=float),
                    np.array([p], dtype=float),
                    np.array([heading]),
                    epoch * self.period_ns,
                    (epoch + 1) * self.period_ns,
                    period_s,
                    self.limits,
                )
                self._loops[i] = loop
                self._send(i, *loop.twist())
                self.last_command[i] = u
        self.counts["commands"] += len(velocities)

    def wait_steered(
        self, timeout_s: float
    ) -> tuple[dict[int, list[float]], dict[int, float], dict[int, int]]:
        """Lockstep unicycles: once every robot's inner loop has ended, each one's ``x[k+1]``
        [m], ``θ[k+1]`` [rad] and clipped sub-steps. Raises :class:`BodyLost` for the first
        robot still steering when no pose came on for ``timeout_s`` [s]."""
        with self._cond:
            progress, deadline = -1, 0.0
            while not all(loop.done for loop in self._loops.values()):
                now = sum(loop.last_ns for loop in self._loops.values())
                if now != progress:  # a pose was answered: the robots are there
                    progress, deadline = now, time.monotonic() + timeout_s
                left = deadline - time.monotonic()
                if left <= 0:
                    lost = next(i for i, loop in self._loops.items() if not loop.done)
                    end = self._loops[lost].end_ns // self.period_ns
                    raise BodyLost(lost, self.body.pose_topic_of(lost), timeout_s, end)
                self._cond.wait(left)
            saturated = {}
            for i, loop in self._loops.items():
                p, heading, saturated[i] = loop.result()
                self._start[i] = (p, heading)
                self.counts["yaw_taken"] += loop.yaw_taken
            self._loops = {}
            return (*self._placed(), saturated)

    def headings(self) -> dict[int, float]:
        """Each robot's newest heading [rad] (a unicycle's)."""
        with self._cond:
            return {i: self._poses[i].heading for i in self.ids if i in self._poses}

    def wait_poses(self, epoch: int | None, timeout_s: float) -> dict[int, list[float]]:
        """Each robot's pose stamped with ``epoch`` (None: the newest, if it came within
        ``timeout_s``) [m].

        Raises :class:`BodyLost` for the first robot none came from within ``timeout_s``.
        """
        want = None if epoch is None else epoch * self.period_ns
        deadline = time.monotonic() + timeout_s

        def have(i: int) -> bool:
            pose = self._poses.get(i)
            if pose is None:
                return False
            if want is None:
                return time.monotonic() - pose.arrived_s <= timeout_s
            return pose.stamp_ns >= want

        with self._cond:
            while not all(have(i) for i in self.ids):
                left = deadline - time.monotonic()
                if left <= 0:
                    lost = next(i for i in self.ids if not have(i))
                    raise BodyLost(
                        lost,
                        self.body.pose_topic_of(lost),
                        timeout_s,
                        -1 if epoch is None else epoch,
                    )
                self._cond.wait(left)
            self._used = {i: self._poses[i].arrived_s for i in self.ids}
            return {i: list(self._poses[i].position) for i in self.ids}

    def wait_subscribed(self, timeout_s: float) -> None:
        """Until every command publisher has a subscriber (the first command is not lost)."""
        deadline = time.monotonic() + timeout_s
        for i, pub in self._publishers.items():
            while not pub.matched():
                if time.monotonic() > deadline:
                    raise BodyLost(i, self.body.command_topic_of(i), timeout_s, 0)
                time.sleep(0.01)  # rclpy has no wait on matching; discovery takes milliseconds

    def command(self, velocities: dict[int, list[float]]) -> None:
        """Send each robot its velocity [scenario m/s] as a ``Twist``."""
        scale = self.body.scale
        for i, u in velocities.items():
            if self.unicycle:  # held for the epoch, steered at every pose
                with self._cond:
                    self._u[i] = np.array(u, dtype=float)
                    self._steer(i, self._poses[i].heading)
            else:
                self._publishers[i].publish([c * scale for c in u], 0.0)
            self.last_command[i] = u
            if i in self._used:  # from the pose's arrival to its command's publish
                self.latency_s.append(time.monotonic() - self._used[i])
        self.counts["commands"] += len(velocities)

    def traffic(self, i: int) -> list[tuple[str, str, bytes]]:
        """Robot ``i``'s last pose placed and last command as ``(what, type, CDR)``, in the
        robot's frame, to record (formation.keys.body)."""
        out: list[tuple[str, str, bytes]] = []
        scale, pose = self.body.scale, self._poses.get(i)
        if pose is not None:
            where = list(pose.robot_xyz) or [c * scale for c in pose.position]
            frame, kind = self.body.frame_id, self.body.pose_type
            cdr = pose_cdr(kind, where, pose.stamp_ns, frame, yaw=pose.heading)
            out.append(("pose", kind, cdr))
        if i in self._twists:
            out.append(("command", self.body.command_type, twist_cdr(*self._twists[i])))
        elif i in self.last_command:
            velocity = [c * scale for c in self.last_command[i]]
            out.append(("command", self.body.command_type, twist_cdr(velocity)))
        return out

    def summary(self) -> dict[str, Any]:
        """The counts, and pose in → command out over the run: p50 and p99 [ms]."""
        out: dict[str, Any] = dict(self.counts)
        if self.latency_s:
            p50, p99 = np.percentile(np.array(self.latency_s) * 1e3, [50, 99])
            out["pose_to_command_ms"] = {"p50": round(float(p50), 3), "p99": round(float(p99), 3)}
        return out

    def close(self) -> None:
        self.link.close()


__all__ = ["FIRST_POSE_S", "RobotBodies"]
