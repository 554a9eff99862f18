"""The plant's robots, with no ROS 2: where each is, what it was sent, one step of the dynamics.

Each robot is a holonomic body that holds the velocity of its last command
(:func:`agent.held_velocity_step`, the function the simulator moves a robot with), so a
stepped run equals ``formation simulate`` to the bit (docs/robots.md).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from agent import held_velocity_step
from formation.scenario import Scenario

Array = npt.NDArray[np.float64]


@dataclass
class Robots:
    """Robots ``ids`` at ``x`` (r, d) [m], at epoch ``epoch`` (stepped clock)."""

    ids: list[int]
    x: Array
    period_s: float
    epoch: int = 0
    queued: dict[int, deque[list[float]]] = field(default_factory=dict)  # stepped: per robot
    held: dict[int, list[float]] = field(default_factory=dict)  # free-running: the last command
    counts: dict[str, int] = field(
        default_factory=lambda: {"commands": 0, "bad_commands": 0, "steps": 0}
    )

    @classmethod
    def of(cls, scenario: Scenario, seed: int | None = None) -> Robots:
        """Every robot of ``scenario`` where the scenario starts it (its initial positions)."""
        ids = scenario.body.robots(scenario.n)
        x0 = scenario.initial_positions(seed)[np.array(ids, dtype=np.int64) - 1]
        return cls(ids, x0.copy(), scenario.control.period_s, queued={i: deque() for i in ids})

    def command(self, robot: int, velocity: list[float]) -> None:
        """A command [m/s]; one that is not finite is counted and taken as a stop."""
        self.counts["commands"] += 1
        if not all(math.isfinite(c) for c in velocity):
            self.counts["bad_commands"] += 1
            velocity = [0.0] * len(velocity)
        self.queued[robot].append(velocity)
        self.held[robot] = velocity

    def ready(self) -> bool:
        """Stepped: every robot's command of this epoch is in."""
        return all(self.queued[i] for i in self.ids)

    def step_epoch(self) -> None:
        """Stepped: each robot holds its command of this epoch for one period."""
        u = np.array([self.queued[i].popleft() for i in self.ids], dtype=float)
        self.x = held_velocity_step(self.x, u, self.period_s)
        self.epoch += 1
        self.counts["steps"] += 1

    def step_for(self, dt_s: float) -> None:
        """Free-running: each robot holds its last command for ``dt_s`` [s] (none yet: at rest)."""
        d = self.x.shape[1]
        u = np.array([self.held.get(i, [0.0] * d) for i in self.ids], dtype=float)
        self.x = held_velocity_step(self.x, u, dt_s)
        self.counts["steps"] += 1

    def stop(self, robot: int) -> None:
        """Free-running: no command for too long: the robot stops (as a robot's watchdog does)."""
        self.held.pop(robot, None)


__all__ = ["Robots"]
