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
is counted and not used; no usable pose for ``pose_timeout_s`` and the body is lost. In
realtime an agent steps only from a pose that came within the last period; while it waits
for one, and at its end, its robots get a zero ``Twist``, and between steps each robot's
command is sent again at every pose it publishes (its watchdog sees the command's rate).
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
from formation.errors import BodyLost, PoseFrameMismatch, QosMismatch, RobotNotAtStart
from formation.scenario import Scenario

log = logging.getLogger("agent.body")
FIRST_POSE_S = 60.0  # [s] for the first pose: the plant or the robot may still be starting
JUMP_MARGIN = 2.0  # a pose may be this many times further than the speed limit allows
# [s] with no first pose, how long before the ROS graph is asked for a publisher whose QoS
# cannot match (an RMW's incompatible-QoS event, where it has one, comes within milliseconds)
GRAPH_CHECK_S = 2.0
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
        self.counts |= {"clipped": 0, "resent": 0, "stale_waits": 0, "stops": 0, "wrong_frame": 0}
        self.counts["empty_frame"] = 0
        self.realtime = scenario.runtime.mode == "realtime"
        self.step_s = scenario.runtime.realtime_period_s or scenario.control.period_s
        self._held: dict[int, list[float]] = {}  # realtime: each robot's command [robot m/s]
        self._mismatch: dict[int, tuple[str, str, str]] = {}  # QoS: offered, requested, policy
        self._lost: set[int] = set()
        self._frames: dict[int, str] = {}  # a frame_id other than the body's, as last seen
        self.last_command: dict[int, list[float]] = {}
        self._used: dict[int, float] = {}  # the arrival of the pose each robot was last placed by
        self.latency_s: list[float] = []  # pose in → command out, per command [s]
        self.unicycle = scenario.control.dynamics == "unicycle"
        self.limits = scenario.control.unicycle.limits
        self.max_speed_m_s = self.limits[0] if self.unicycle else self.body.max_speed_m_s
        # Without a speed limit, how far a body may move in one epoch before a pose counts
        # as a jump [m]: the shape's size, twice over (a step is a fraction of the errors).
        span = float(np.ptp(scenario.offsets, axis=0).max()) if scenario.n > 1 else 1.0
        self.max_jump_m = 2.0 * (span + 2.0 * scenario.initial.spread_m) + 1.0
        self._u: dict[int, Array] = {}  # a unicycle's look-ahead velocity this epoch [m/s]
        # lockstep unicycles: each robot's inner loop of this epoch, and its x[k], θ[k]
        self.stepped = self.unicycle and scenario.runtime.mode != "realtime"
        self._loops: dict[int, InnerLoop] = {}
        self._start: dict[int, tuple[list[float], float]] = {}
        self.counts["yaw_taken"] = 0
        self._twists: dict[int, tuple[list[float], float]] = {}  # last sent [robot m/s, rad/s]
        self._subscriptions = [
            self.link.poses(
                self.body.pose_topic_of(i), partial(self._on_pose, i), partial(self._on_mismatch, i)
            )
            for i in self.ids
        ]
        self._publishers = {
            i: self.link.command_publisher(self.body.command_topic_of(i)) for i in self.ids
        }

    def _on_pose(self, agent: int, xyz: list[float], stamp: int, yaw: float, frame: str) -> None:
        """On the link's thread: keep the newest usable pose of ``agent`` (a unicycle's: and
        send its next inner-loop command)."""
        if frame and frame != self.body.frame_of(agent):  # coordinates the scenario has no map of
            with self._cond:
                self.counts["poses"] += 1
                self.counts["wrong_frame"] += 1
                self._frames[agent] = frame
                self._cond.notify_all()
            return
        transform = self.body.transform_of(agent)
        if transform is not None:  # its own frame (odom) → the world's
            xyz, yaw = transform.to_world(xyz, yaw)
        d, scale = self.scenario.dimension, self.body.scale
        centre = position = [c / scale for c in xyz[:d]]
        if self.unicycle:  # the look-ahead point of the axle's centre
            position = pose_point(centre, yaw, self.limits[2])
        with self._cond:
            self.counts["poses"] += 1
            # no frame_id claims no other frame: taken as the declared one, and counted
            self.counts["empty_frame"] += not frame
            if not all(math.isfinite(c) for c in [*position, yaw]):
                self.counts["bad_poses"] += 1
                return
            last, now = self._poses.get(agent), time.monotonic()
            if last is not None and math.dist(last.position, position) > self.jump_m(
                now - last.arrived_s
            ):
                self.counts["jumps"] += 1
                return
            self._poses[agent] = _Pose(stamp, position, now, yaw, tuple(xyz), centre)
            self._cond.notify_all()
            if agent in self._held:  # realtime: the command again, at the robot's pose rate
                sent = self._in_frame(agent, self._held[agent])
                self._publishers[agent].publish(sent, 0.0)
                self._twists[agent] = (sent, 0.0)
                self.counts["resent"] += 1
            if self.unicycle and agent in self._u:
                self._steer(agent, yaw)
            if agent in self._loops:
                self._answer(agent, self._loops[agent], centre, yaw, stamp)

    def _in_frame(self, agent: int, velocity: list[float]) -> list[float]:
        """A holonomic robot's velocity [robot m/s] in its command frame: as is (``world``), or
        turned by minus its newest heading into its own frame (``body``, REP 103)."""
        if self.body.command_frame == "world":
            transform = self.body.transform_of(agent)  # the world's velocity, in its own frame
            return velocity if transform is None else transform.velocity_in_frame(velocity)
        heading = self._poses[agent].heading  # in the world, as the velocity
        c, s = math.cos(heading), math.sin(heading)
        x, y, *z = velocity
        return [c * x + s * y, -s * x + c * y, *z]

    def jump_m(self, since_s: float) -> float:
        """How far a body may have moved since a pose ``since_s`` ago [m]: at its speed limit
        for at least an epoch, ``JUMP_MARGIN`` times over; without a limit, ``max_jump_m``."""
        if self.max_speed_m_s is None:
            return self.max_jump_m
        speed = self.max_speed_m_s
        if self.unicycle:  # the look-ahead point also swings with the turn
            speed += self.limits[2] * self.limits[1]
        return JUMP_MARGIN * speed * max(since_s, self.step_s)

    def _on_mismatch(self, agent: int, offered: str, requested: str, policy: str) -> None:
        with self._cond:
            self._mismatch[agent] = (offered, requested, policy)
            self._cond.notify_all()

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
        if agent in self._u:  # none once stopped
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
        """Each robot's pose stamped with ``epoch`` (None: the newest, if it came within the
        last period) [m].

        Realtime (``epoch`` None): a robot whose newest pose is older than a period is waited
        for, stopped (a zero ``Twist``) once it is two periods old, and lost ``timeout_s``
        after that pose came. Raises :class:`BodyLost` for the first robot lost,
        :class:`QosMismatch` for one whose publisher cannot match the subscription.
        """
        want = None if epoch is None else epoch * self.period_ns
        began = time.monotonic()

        def have(i: int) -> bool:
            pose = self._poses.get(i)
            if pose is None:
                return False
            if want is None:
                return time.monotonic() - pose.arrived_s <= min(self.step_s, timeout_s)
            return pose.stamp_ns >= want

        def waited_s() -> float:
            return time.monotonic() - began

        def lost_at(i: int) -> float:  # from its newest pose, else from now
            pose = self._poses.get(i)
            return timeout_s + (began if pose is None or want is not None else pose.arrived_s)

        with self._cond:
            waited = False
            while not all(have(i) for i in self.ids):
                missing = [i for i in self.ids if not have(i)]
                for i in missing:
                    if (
                        i not in self._poses
                        and i not in self._mismatch
                        and waited_s() > GRAPH_CHECK_S
                    ):
                        refused = self.link.refused_by(self.body.pose_topic_of(i))
                        if refused is not None:
                            self._mismatch[i] = refused
                    if i not in self._poses and i in self._mismatch:
                        raise QosMismatch(i, self.body.pose_topic_of(i), *self._mismatch[i])
                    if i not in self._poses and i in self._frames:
                        topic = self.body.pose_topic_of(i)
                        raise PoseFrameMismatch(i, topic, self._frames[i], *self._declared(i))
                now = time.monotonic()
                lost = [i for i in missing if lost_at(i) <= now]
                if lost:
                    self._stop(lost)
                    self._lost.update(lost)
                    raise BodyLost(
                        lost[0],
                        self.body.pose_topic_of(lost[0]),
                        timeout_s,
                        -1 if epoch is None else epoch,
                    )
                if want is None and not waited:
                    waited = True
                    self.counts["stale_waits"] += 1
                stale = [i for i in missing if i in self._poses and self._age(i) > 2 * self.step_s]
                self._stop(stale)  # its pose stopped: so does the robot, until it is back
                self._cond.wait(min(min(lost_at(i) for i in missing) - now, self.step_s))
            self._used = {i: self._poses[i].arrived_s for i in self.ids}
            return {i: list(self._poses[i].position) for i in self.ids}

    def _declared(self, i: int) -> tuple[str, str]:
        """The frame robot ``i``'s poses are declared in, and the field declaring it."""
        ts = self.body.transforms
        k = next((k for k, t in enumerate(ts) if t.agent == i), None)
        field = "body.frame_id" if k is None else f"body.transforms[{k}].frame_id"
        return self.body.frame_of(i), field

    def pose_arrived(self, i: int) -> float:
        """When robot ``i``'s newest usable pose came (``time.monotonic()``) [s]."""
        with self._cond:
            return self._poses[i].arrived_s

    def last_twist(self, i: int) -> tuple[list[float], float] | None:
        """The last ``Twist`` sent to robot ``i``: linear [robot m/s], angular.z [rad/s]."""
        with self._cond:
            return self._twists.get(i)

    def _age(self, i: int) -> float:
        return time.monotonic() - self._poses[i].arrived_s

    def check_start(self, starts: dict[int, list[float]]) -> None:
        """Raise :class:`RobotNotAtStart` for the first robot whose newest pose is further
        than ``start_tolerance_m`` from its start [m]."""
        tolerance = self.body.start_tolerance_m
        with self._cond:
            for i in self.ids:
                pose = self._poses[i].position
                if not math.dist(pose, starts[i]) <= tolerance:
                    raise RobotNotAtStart(i, self.body.pose_topic_of(i), pose, starts[i], tolerance)

    def stop(self, timeout_s: float = 2.0) -> None:
        """Realtime: a zero ``Twist`` to every robot, sent no more (the end, a signal, a loss),
        and waited for up to ``timeout_s``: the process may end next, and its zero with it."""
        with self._cond:
            self._stop(self.ids)
        if not self.realtime:
            return  # no zero was sent
        deadline = time.monotonic() + timeout_s
        for i, pub in self._publishers.items():
            if i in self._lost:
                continue  # no robot there to acknowledge it
            if not pub.delivered(max(deadline - time.monotonic(), 0.0)):
                log.warning("agent %d: its robot's zero Twist was not acknowledged", i)

    def _stop(self, ids: list[int]) -> None:
        """A zero ``Twist`` to robots ``ids`` that are moving (realtime; the lock held): the
        stepped plant moves only by the commands of an epoch, which a zero would be."""
        for i in ids:
            if self.realtime and (i in self._held or i in self._u):
                self._held.pop(i, None)
                self._u.pop(i, None)
                self._publishers[i].publish([0.0] * self.scenario.dimension, 0.0)
                self._twists[i] = ([0.0] * self.scenario.dimension, 0.0)
                self.counts["stops"] += 1

    def wait_subscribed(self, timeout_s: float) -> None:
        """Until every command publisher has a subscriber (the first command is not lost)."""
        deadline = time.monotonic() + timeout_s
        for i, pub in self._publishers.items():
            while not pub.matched():
                if time.monotonic() > deadline:
                    raise BodyLost(i, self.body.command_topic_of(i), timeout_s, 0)
                time.sleep(0.01)  # rclpy has no wait on matching; discovery takes milliseconds

    def command(self, velocities: dict[int, list[float]]) -> None:
        """Send each robot its velocity [scenario m/s] as a ``Twist``, a holonomic one's
        clipped to ``max_speed_m_s`` (counted)."""
        scale, limit = self.body.scale, self.body.max_speed_m_s
        for i, u in velocities.items():
            if self.unicycle:  # held for the epoch, steered at every pose
                with self._cond:
                    self._u[i] = np.array(u, dtype=float)
                    self._steer(i, self._poses[i].heading)
            else:
                speed = math.hypot(*u)
                if limit is not None and speed > limit:
                    u = [c * (limit / speed) for c in u]
                    self.counts["clipped"] += 1
                twist = [c * scale for c in u]
                with self._cond:
                    sent = self._in_frame(i, twist)
                    self._publishers[i].publish(sent, 0.0)
                    self._twists[i] = (sent, 0.0)
                    if self.realtime:  # in the pose's frame: turned again at each send
                        self._held[i] = twist
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

    def status_counts(self) -> dict[str, int]:
        """The counts a run's summary adds up over its agents (``body_`` before each name)."""
        with self._cond:
            return {f"body_{name}": n for name, n in self.counts.items()}

    def close(self) -> None:
        self.link.close()


__all__ = ["FIRST_POSE_S", "GRAPH_CHECK_S", "RobotBodies"]
