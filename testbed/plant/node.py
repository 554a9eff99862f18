"""The headless ROS 2 plant: one node that owns every robot of a scenario (docs/robots.md).

It subscribes to each robot's command topic (``geometry_msgs/msg/Twist``) and publishes its
pose (the scenario's pose type), on the topics and QoS of the scenario's ``[body]``. Two clocks:

- **stepped**: the pose of epoch 0 goes to each robot once both its topics are matched, and
  again every ``FIRST_POSE_S`` until its first command comes (a DDS reader that matches
  after the writer misses what the writer sent in between); once every robot's command of
  epoch ``k`` is in, every robot moves one period and the poses
  go out stamped ``k + 1`` (sim time ``(k + 1) T``). It follows the scenario's membership:
  only the robots whose agent takes part at ``k`` are waited for and move, and a robot whose
  agent joins or restarts at ``k`` gets its pose as at epoch 0, until its first command. A unicycle moves one sub-step of the
  simulator's inner loop per command, and its poses go out stamped with the sub-step's sim
  time, ``inner_steps`` an epoch, the last one ``(k + 1) T``. A lockstep run through it
  equals ``formation simulate`` to the bit. The sim time goes out on ``/clock`` at each step
  and every ``FIRST_POSE_S`` (for nodes with ``use_sim_time``).
- **free**: every ``1 / rate_hz`` each robot moves by the last command it got (stopping when
  none came for ``pose_timeout_s``), and the poses go out stamped with the wall clock, as a
  robot does.
"""

from __future__ import annotations

import logging
import threading
import time
from functools import partial
from typing import Any, Literal

from body import NS_PER_S, BodyLink, open_body_link
from formation.scenario import Scenario
from testbed.plant.robots import Robots

log = logging.getLogger("ros2-plant")
PlantTiming = Literal["stepped", "free"]  # how the plant moves its robots (above)
FIRST_POSE_S = 0.1  # [s] how often the stepped clock sends a starting robot's pose
COUNTS_WAIT_S = 5.0  # [s] the longest the counts wait for the robots' lock


class Plant:
    """The plant's node over :class:`Robots`. Commands come on the link's thread, the clock
    runs on a thread of its own; one lock keeps the robots."""

    def __init__(
        self,
        scenario: Scenario,
        clock: PlantTiming = "stepped",
        rate_hz: float | None = None,
        seed: int | None = None,
        name: str = "formation_plant",
        session: Any = None,
    ) -> None:
        self.scenario, self.body, self.clock = scenario, scenario.body, clock
        self.robots = Robots.of(scenario, seed)
        if not self.robots.ids:
            raise ValueError(f"{scenario.name}: no agent has a ROS 2 body (body.kind)")
        self.period_ns = round(scenario.control.period_s * NS_PER_S)
        self.link: BodyLink = open_body_link(name, self.body, session)
        self.done = threading.Event()  # stepped: the scenario's last epoch is reached
        self.closing = threading.Event()
        self._lock = threading.Lock()
        # stepped: robots whose agent starts (at epoch 0, a join, a restart) and has not sent
        # its first command yet
        self._awaited = self.robots.starting(0)
        self._started = False  # every robot taking part at epoch 0 has sent a command
        self._last_command_ns: dict[int, int] = {}
        self._publishers = {  # each robot in its declared frame (body.transforms)
            i: self.link.pose_publisher(self.body.pose_topic_of(i), self.body.frame_of(i))
            for i in self.robots.ids
        }
        self._subscriptions = {
            i: self.link.commands(self.body.command_topic_of(i), partial(self._on_command, i))
            for i in self.robots.ids
        }
        # stepped: the sim time on /clock, for a node of the user's with use_sim_time
        self._clock = self.link.clock_publisher() if clock == "stepped" else None
        rate = rate_hz or 1.0 / (scenario.runtime.realtime_period_s or scenario.control.period_s)
        self.dt_s = 1.0 / rate
        loop = self._starting_poses if clock == "stepped" else self._free_running
        self._thread = threading.Thread(target=loop, name=f"plant-{clock}", daemon=True)
        self._thread.start()

    def _publish(self, rows: list[int], stamp_ns: int) -> None:
        scale = self.body.scale
        for r in rows:
            i = self.robots.ids[r]
            position = [float(c) * scale for c in self.robots.x[r]]
            yaw, transform = self.robots.yaw(r), self.body.transform_of(i)
            if transform is not None:  # as the robot publishes it, in its own frame
                position, yaw = transform.from_world(position), yaw - transform.rotation_rad
            self._publishers[i].publish(position, stamp_ns, yaw)

    def _starting_poses(self) -> None:
        """Stepped: the pose of each robot whose agent starts, once its topics are matched,
        every ``FIRST_POSE_S`` until its first command comes."""
        while not self.closing.wait(FIRST_POSE_S):
            with self._lock:
                self._tick()  # again, for a node that has just joined (its QoS is volatile)
                for r, i in enumerate(self.robots.ids):
                    if (
                        i in self._awaited
                        and self._publishers[i].matched()
                        and self._subscriptions[i].matched()
                    ):
                        self._publish([r], self._stamp_ns())

    def _stamp_ns(self) -> int:
        """The sim time of the robots' state: ``(k + s / inner_steps) T`` [ns]."""
        steps = self.robots.limits[3]
        return self.robots.epoch * self.period_ns + self.robots.substep * self.period_ns // steps

    def _tick(self) -> None:
        """Stepped: the robots' sim time on ``/clock``."""
        assert self._clock is not None
        self._clock.publish(self._stamp_ns())

    def _on_command(self, robot: int, velocity: list[float], turn_rad_s: float) -> None:
        transform = self.body.transform_of(robot)
        world = self.body.command_frame == "world" and self.robots.heading is None
        if transform is not None and world:  # a holonomic cmd_vel in its own frame
            velocity = transform.velocity_to_world(velocity)
        u = [c / self.body.scale for c in velocity[: self.scenario.dimension]]
        with self._lock:
            self.robots.command(robot, u, turn_rad_s)
            self._last_command_ns[robot] = time.monotonic_ns()
            if self.clock != "stepped":
                return
            self._awaited.discard(robot)
            if not self._awaited and not self._started:
                self._started = True
                log.info("stepped: every robot has sent its first command")
            while self.robots.ready():
                self.robots.step()
                self._tick()  # before the poses it stamps: a node sees the time, then them
                self._publish(list(range(len(self.robots.ids))), self._stamp_ns())
                k = self.robots.epoch
                if self.robots.substep:
                    continue
                self._awaited |= self.robots.starting(k)  # a join or a restart at k
                if k == self.scenario.epochs:
                    log.info("stepped: epoch %d, the scenario's last, reached", k)
                    self.done.set()

    def _free_running(self) -> None:
        """Free-running: every ``dt_s`` move by the held commands, publish the poses."""
        next_s = time.monotonic()
        stale_ns = self.body.pose_timeout_s * NS_PER_S
        while not self.closing.wait(max(0.0, next_s - time.monotonic())):
            next_s += self.dt_s
            with self._lock:
                now = time.monotonic_ns()
                for i, at in list(self._last_command_ns.items()):
                    if now - at > stale_ns:
                        self.robots.stop(i)
                self.robots.step_for(self.dt_s)
                self._publish(list(range(len(self.robots.ids))), time.time_ns())

    @property
    def counts(self) -> dict[str, int]:
        """The robots' counts and epoch; read unlocked after ``COUNTS_WAIT_S`` (logged), so a
        callback stuck inside ROS 2 while holding the lock cannot hang the plant's exit."""
        locked = self._lock.acquire(timeout=COUNTS_WAIT_S)
        try:
            if not locked:
                log.warning(
                    "the robots' lock was held for %g s; counts read without it", COUNTS_WAIT_S
                )
            return {**self.robots.counts, "epoch": self.robots.epoch}
        finally:
            if locked:
                self._lock.release()

    def close(self) -> None:
        self.closing.set()
        self._thread.join(timeout=2.0)
        self.link.close()


__all__ = ["Plant", "PlantTiming"]
