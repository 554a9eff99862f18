"""How the simulator moves an agent whose body is a ROS 2 robot (docs/robots.md): as the robot
moves, so that a lockstep run through the stepped plant equals ``formation simulate`` to the bit.

- A holonomic robot is sent the velocity to ``x[k+1]`` and goes where it takes it
  (:func:`agent.body_step`).
- A unicycle robot steers by the same inner loop as a simulated unicycle, so only the
  reference agent differs: its robot is steered toward its trajectory
  (:func:`agent.drive_unicycle` at :func:`agent.body_velocity`) instead of following it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from agent import body_step, body_velocity, drive_unicycle
from formation.scenario import Scenario

Array = npt.NDArray[np.float64]
Ints = npt.NDArray[np.int64]


@dataclass(frozen=True)
class RobotRows:
    """The rows of a batch's agents whose body is a robot, and what moves them."""

    rows: Ints  # (r,) rows ``i − 1`` of the robots
    reference_row: int | None  # the reference agent's row, if its body is a robot
    period_s: float
    limits: tuple[float, float, float, int] | None  # a unicycle's (agent.drive_unicycle)

    @classmethod
    def of(cls, scenario: Scenario) -> RobotRows:
        rows = np.array(scenario.body.robots(scenario.n), dtype=np.int64) - 1
        r = scenario.reference_agent - 1
        reference_row = r if r in rows.tolist() else None
        ctl = scenario.control
        limits = ctl.unicycle.limits if ctl.dynamics == "unicycle" else None
        return cls(rows, reference_row, ctl.period_s, limits)

    def step(
        self,
        xk: Array,
        x_next: Array,
        ref_next: Array,
        th: tuple[Array, Array] | None,
        saturated: npt.NDArray[np.int64] | None,
    ) -> None:
        """Move the robots of ``x_next`` (B, n, d) from ``xk`` (B, n, d) as they move
        (``ref_next`` (d,): the reference's ``x[k+1]``); unicycles: ``th`` is ``(θ[k], θ[k+1])``
        (B, n) each, ``saturated`` (B, n), both overwritten for the reference robot."""
        if not self.rows.size:
            return
        r = self.reference_row
        if self.limits is None:  # sent a velocity, and go where it takes them
            if r is not None:  # sent toward its trajectory
                x_next[:, r] = ref_next
            x_next[:, self.rows] = body_step(xk[:, self.rows], x_next[:, self.rows], self.period_s)
            return
        if r is None or th is None or saturated is None:
            return
        u = body_velocity(xk[:, r], ref_next, self.period_s)  # toward its trajectory
        x_next[:, r], th[1][:, r], saturated[:, r] = drive_unicycle(
            xk[:, r], th[0][:, r], u, self.period_s, self.limits
        )


__all__ = ["RobotRows"]
