"""The headless ROS 2 plant: one node that owns every robot of a scenario (docs/robots.md).

It subscribes to each robot's command topic (``geometry_msgs/msg/Twist``) and publishes its
pose (the scenario's pose type), on the topics and QoS of the scenario's ``[body]``. Two clocks:

- **stepped**: the pose of epoch 0 goes to each robot once both its topics are matched, and
  again every ``FIRST_POSE_S`` until its first command comes (a DDS reader that matches
  after the writer misses what the writer sent in between); once every robot's command of
  epoch ``k`` is in, every robot moves one period and the poses
  go out stamped ``k + 1`` (sim time ``(k + 1) T``). A lockstep run through it equals
  ``formation simulate`` to the bit.
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

from formation.scenario import Scenario
from shell import NS_PER_S, RosNode, open_ros_node, pose_message, twist_velocity
from testbed.plant.robots import Robots

log = logging.getLogger("ros2-plant")
Clock = Literal["stepped", "free"]
FIRST_POSE_S = 0.1  # [s] how often the stepped clock sends epoch 0's poses until commanded


class Plant:
    """The plant's node over :class:`Robots`; callbacks run on the node's one thread."""

    def __init__(
        self,
        scenario: Scenario,
        clock: Clock = "stepped",
        rate_hz: float | None = None,
        seed: int | None = None,
        name: str = "formation_plant",
    ) -> None:
        self.scenario, self.body, self.clock = scenario, scenario.body, clock
        self.robots = Robots.of(scenario, seed)
        if not self.robots.ids:
            raise ValueError(f"{scenario.name}: no agent has a ROS 2 body (body.kind)")
        self.period_ns = round(scenario.control.period_s * NS_PER_S)
        self.node: RosNode = open_ros_node(name, self.body)
        self.done = threading.Event()  # stepped: the scenario's last epoch is reached
        self._commanded: set[int] = set()  # stepped: robots whose first command came
        self._last_command_ns: dict[int, int] = {}
        self._publishers = {
            i: self.node.publisher(
                self.body.pose_topic_of(i), self.node.pose_class, self.body.pose_qos
            )
            for i in self.robots.ids
        }
        self._subscriptions = {
            i: self.node.subscribe(
                self.body.command_topic_of(i),
                self.node.command_class,
                self.body.command_qos,
                partial(self._on_command, i),
            )
            for i in self.robots.ids
        }
        if clock == "stepped":
            self._timer = self.node.node.create_timer(FIRST_POSE_S, self._first_poses)
        else:
            rate = rate_hz or 1.0 / (
                scenario.runtime.realtime_period_s or scenario.control.period_s
            )
            self.dt_s = 1.0 / rate
            self._timer = self.node.node.create_timer(self.dt_s, self._tick)

    def _publish(self, rows: list[int], stamp_ns: int) -> None:
        scale = self.body.scale
        for r in rows:
            i = self.robots.ids[r]
            position = [float(c) * scale for c in self.robots.x[r]]
            msg = pose_message(self.node.pose_class, position, stamp_ns, self.body.frame_id)
            self._publishers[i].publish(msg)

    def _first_poses(self) -> None:
        """Stepped: epoch 0's pose to each robot not commanded yet whose topics are matched."""
        for r, i in enumerate(self.robots.ids):
            if (
                i not in self._commanded
                and self._publishers[i].get_subscription_count() > 0
                and self._subscriptions[i].get_publisher_count() > 0
            ):
                self._publish([r], 0)
        if len(self._commanded) == len(self.robots.ids):
            self._timer.cancel()
            log.info("stepped: every robot has sent its first command")

    def _on_command(self, robot: int, msg: Any) -> None:
        u = [c / self.body.scale for c in twist_velocity(msg, self.scenario.dimension)]
        self.robots.command(robot, u)
        self._last_command_ns[robot] = time.monotonic_ns()
        self._commanded.add(robot)
        if self.clock != "stepped":
            return
        while self.robots.ready():
            self.robots.step_epoch()
            k = self.robots.epoch
            self._publish(list(range(len(self.robots.ids))), k * self.period_ns)
            if k == self.scenario.epochs:
                log.info("stepped: epoch %d, the scenario's last, reached", k)
                self.done.set()

    def _tick(self) -> None:
        """Free-running: move by the held commands for one tick, publish the poses."""
        now = time.monotonic_ns()
        stale_ns = self.body.pose_timeout_s * NS_PER_S
        for i, at in list(self._last_command_ns.items()):
            if now - at > stale_ns:
                self.robots.stop(i)
        self.robots.step_for(self.dt_s)
        self._publish(list(range(len(self.robots.ids))), time.time_ns())

    @property
    def counts(self) -> dict[str, int]:
        return {**self.robots.counts, "epoch": self.robots.epoch}

    def close(self) -> None:
        self.node.close()


__all__ = ["Clock", "Plant"]
