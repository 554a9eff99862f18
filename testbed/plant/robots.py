"""The plant's robots, with no ROS 2: where each is, what it was sent, one step of the dynamics.

Each robot is a holonomic body that holds the velocity of its last command
(:func:`agent.held_velocity_step`, the function the simulator moves a robot with), so a
stepped run equals ``formation simulate`` to the bit (docs/robots.md). A unicycle holds its
last ``linear.x``, ``angular.z``, clipped to its limits, and moves its axle's centre along the
exact arc (:func:`agent.unicycle_arc`); stepped, each command is one sub-step of the
simulator's inner loop (:func:`agent.unicycle_substep`, from the look-ahead point as the
simulator keeps it), ``inner_steps`` an epoch. Stepped, a robot whose agent is out of the team
at an epoch (the scenario's events) is not waited for and stays where it is, as the
simulator keeps a body out of the team.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from agent import (
    axle_centre,
    held_velocity_step,
    substep_s,
    unicycle_arc,
    unicycle_substep,
    wrap_angle,
)
from formation.robots import initial_headings
from formation.scenario import Scenario

Array = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]


@dataclass
class Robots:
    """Robots ``ids`` at ``x`` (r, d) [m], at epoch ``epoch`` and its sub-step ``substep``
    (stepped clock; a unicycle's inner loop)."""

    ids: list[int]
    x: Array  # positions; a unicycle's axle centres [m]
    period_s: float
    heading: Array | None = None  # a unicycle's (r,) [rad]; stepped: wrapped at an epoch's end
    lookahead: Array | None = None  # a unicycle's (r, 2) look-ahead points [m] (stepped)
    limits: tuple[float, float, float, int] = (0.0, 0.0, 0.0, 1)  # a unicycle's (Unicycle.limits)
    turn: dict[int, float] = field(default_factory=dict)  # a unicycle's held angular.z [rad/s]
    present: Mask | None = None  # stepped: (E + 1, r) the robot's agent takes part at epoch k
    epoch: int = 0
    substep: int = 0
    # stepped: each robot's commands not yet used, (linear [m/s], angular.z [rad/s])
    queued: dict[int, deque[tuple[list[float], float]]] = field(default_factory=dict)
    held: dict[int, list[float]] = field(default_factory=dict)  # free-running: the last command
    counts: dict[str, int] = field(
        default_factory=lambda: {"commands": 0, "bad_commands": 0, "steps": 0}
    )

    @classmethod
    def of(cls, scenario: Scenario, seed: int | None = None) -> Robots:
        """Every robot of ``scenario`` where the scenario starts it (its initial positions)."""
        ids = scenario.body.robots(scenario.n)
        rows = np.array(ids, dtype=np.int64) - 1
        x0 = scenario.initial_positions(seed)[rows]
        period_s = scenario.control.period_s
        queued: dict[int, deque[tuple[list[float], float]]] = {i: deque() for i in ids}
        present = scenario.membership.present[:, rows]
        if scenario.control.dynamics != "unicycle":
            return cls(ids, x0.copy(), period_s, present=present, queued=queued)
        limits = scenario.control.unicycle.limits
        th0 = initial_headings(scenario.seed if seed is None else seed, scenario.n)[rows]
        centre = axle_centre(x0, th0, limits[2])  # the look-ahead point at x0
        return cls(
            ids, centre, period_s, th0.copy(), x0.copy(), limits, present=present, queued=queued
        )

    def command(self, robot: int, velocity: list[float], turn_rad_s: float = 0.0) -> None:
        """A command [m/s] (a unicycle's: ``linear.x`` and ``angular.z`` [rad/s]); one that is
        not finite is counted and taken as a stop."""
        self.counts["commands"] += 1
        if not all(math.isfinite(c) for c in [*velocity, turn_rad_s]):
            self.counts["bad_commands"] += 1
            velocity, turn_rad_s = [0.0] * len(velocity), 0.0
        self.queued[robot].append((velocity, turn_rad_s))
        self.held[robot] = velocity
        self.turn[robot] = turn_rad_s

    def taking_part(self, epoch: int) -> list[int]:
        """Stepped: the rows of the robots whose agent takes part at ``epoch``."""
        if self.present is None:
            return list(range(len(self.ids)))
        return np.flatnonzero(self.present[min(epoch, len(self.present) - 1)]).tolist()

    def starting(self, epoch: int) -> set[int]:
        """Stepped: the robots whose agent starts at ``epoch``: the run's, a join's, a restart's."""
        if self.present is None:
            return set(self.ids) if epoch == 0 else set()
        if epoch >= len(self.present):
            return set()
        new = self.present[epoch] & ~self.present[epoch - 1] if epoch else self.present[0]
        return {self.ids[r] for r in np.flatnonzero(new).tolist()}

    def ready(self) -> bool:
        """Stepped: every command of this epoch (a unicycle's: sub-step) is in, from the robots
        whose agent takes part in it; none is awaited past the scenario's last epoch."""
        if self.present is not None and self.epoch >= len(self.present) - 1:
            return False
        return all(self.queued[self.ids[r]] for r in self.taking_part(self.epoch))

    def step(self) -> None:
        """Stepped: each robot taking part holds its next command for one period (a unicycle:
        one sub-step of it, ``T / inner_steps``); the others stay where they are."""
        on = self.taking_part(self.epoch)
        sent = [self.queued[self.ids[r]].popleft() for r in on]
        u = np.array([velocity for velocity, _ in sent], dtype=float).reshape(
            len(on), self.x.shape[1]
        )
        self.counts["steps"] += 1
        if self.heading is None or self.lookahead is None:
            self.x[on] = held_velocity_step(self.x[on], u, self.period_s)
            self.epoch += 1
            return
        turn = np.array([turn for _, turn in sent], dtype=float)
        v, w = self._clipped(u[:, 0], turn)
        dt, look = substep_s(self.period_s, self.limits), self.limits[2]
        self.x[on], self.heading[on], self.lookahead[on] = unicycle_substep(
            self.lookahead[on], self.heading[on], v, w, dt, look
        )
        self.substep += 1
        if self.substep == self.limits[3]:  # the epoch's end, where the simulator wraps
            self.heading[on] = wrap_angle(self.heading[on])
            self.epoch, self.substep = self.epoch + 1, 0

    def _clipped(self, v: Array, w: Array) -> tuple[Array, Array]:
        """``linear.x``, ``angular.z`` clipped to the limits, as the robot's motors would."""
        return np.clip(v, -self.limits[0], self.limits[0]), np.clip(
            w, -self.limits[1], self.limits[1]
        )

    def step_for(self, dt_s: float) -> None:
        """Free-running: each robot holds its last command for ``dt_s`` [s] (none yet: at rest)."""
        d = self.x.shape[1]
        u = np.array([self.held.get(i, [0.0] * d) for i in self.ids], dtype=float)
        if self.heading is None:
            self.x = held_velocity_step(self.x, u, dt_s)
        else:
            w = np.array([self.turn.get(i, 0.0) for i in self.ids], dtype=float)
            v, w = self._clipped(u[:, 0], w)
            self.x, heading = unicycle_arc(self.x, self.heading, v, w, dt_s)
            self.heading = wrap_angle(heading)
        self.counts["steps"] += 1

    def stop(self, robot: int) -> None:
        """Free-running: no command for too long: the robot stops (as a robot's watchdog does)."""
        self.held.pop(robot, None)
        self.turn.pop(robot, None)

    def yaw(self, row: int) -> float:
        """Robot ``row``'s heading [rad] (0 for a holonomic robot)."""
        return 0.0 if self.heading is None else float(self.heading[row])


__all__ = ["Robots"]
