"""A unicycle robot's inner loop in lockstep: the agent's half of the stepped plant's sub-steps.

Each epoch the agent drives its robot's look-ahead point at the velocity ``u`` of its
consensus step, as :func:`agent.control.drive_unicycle` does: at each of ``inner_steps``
sub-steps it answers the robot's pose with the ``Twist`` ``(v, ω) = unicycle_twist(θ, u)``,
and the stepped plant moves every robot one sub-step once every twist is in
(docs/robots.md). The pose's stamp that ends the epoch is ``(k + 1) T``.

The heading: a pose carries its yaw in a quaternion, rounded and wrapped to ``(−π, π]``,
while the simulator's heading is wrapped only at an epoch's end and its cosine sees every
bit. So the agent keeps the heading its last twist gives (the sub-step the plant integrates,
:func:`agent.control.unicycle_substep`) where the pose's yaw agrees with it to
``YAW_AGREES_RAD``, and takes the pose's yaw otherwise: a robot that turns otherwise than it
was sent is followed. The position is the pose's, ``c + l h(θ)`` of its axle's centre; at
an epoch where the robot starts (the run's first, a join or a restart) the agent keeps the
state it expects (the scenario's ``x[0]``, or netem's last state of it) where the pose agrees
with it to ``POINT_AGREES_M``: ``c + l h(θ)`` of the centre the plant computed from it is
that point only to within its rounding (:func:`confirmed_pose`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from agent.control import (
    lookahead_point,
    substep_s,
    unicycle_substep,
    unicycle_twist,
    wrap_angle,
)

Array = npt.NDArray[np.float64]
YAW_AGREES_RAD = 1e-9  # [rad] far above a quaternion's rounding (~1e-16), far below a turn
POINT_AGREES_M = 1e-9  # [m] far above c + l h(θ)'s rounding, far below a move


def confirmed_heading(expected: float, yaw: float) -> tuple[float, bool]:
    """The heading [rad] a pose's ``yaw`` [rad] confirms: ``expected`` (not wrapped) where the
    two agree to ``YAW_AGREES_RAD``, else the yaw, unwrapped next to it; and whether they agreed."""
    off = float(wrap_angle(np.array([yaw - expected]))[0])
    if abs(off) <= YAW_AGREES_RAD:
        return expected, True
    return expected + off, False


def confirmed_pose(
    expected: tuple[list[float], float], centre: list[float], yaw: float, lookahead_m: float
) -> tuple[list[float], float, bool]:
    """The look-ahead point [m] and heading [rad] a pose (axle centre [m], yaw [rad]) gives a
    robot that starts where the agent ``expected`` it, ``(x, θ)``: the expected ones where
    both agree; and whether they did."""
    heading, turned = confirmed_heading(expected[1], yaw)
    point = pose_point(centre, heading, lookahead_m)
    if turned and math.dist(point, expected[0]) <= POINT_AGREES_M:
        return list(expected[0]), heading, True
    return point, heading, False


def pose_point(centre: list[float], heading: float, lookahead_m: float) -> list[float]:
    """A pose's look-ahead point ``c + l h(θ)`` [m] (the agent's state) of its axle's centre."""
    point = lookahead_point(np.array([centre]), np.array([heading]), lookahead_m)
    return [float(c) for c in point[0]]


@dataclass
class InnerLoop:
    """One robot's inner loop over epoch ``k``: from the look-ahead point ``p`` and heading
    of ``x[k]``, the twists that drive ``p`` at ``u`` until the pose stamped ``end_ns``."""

    u: Array  # (1, 2) the look-ahead point's velocity this epoch [m/s]
    p: Array  # (1, 2) the look-ahead point at the last pose [m]
    heading: Array  # (1,) at the last pose, not wrapped within the epoch [rad]
    last_ns: int  # the stamp of the last pose answered (or settled at the epoch's start)
    end_ns: int  # the stamp of the epoch's last pose, ``(k + 1) T``
    period_s: float
    limits: tuple[float, float, float, int]  # formation.robots.Unicycle.limits
    sent: tuple[Array, Array] | None = None  # the last twist, (1,) v [m/s] and ω [rad/s]
    saturated: int = 0  # sub-steps whose twist was clipped
    yaw_taken: int = 0  # poses whose yaw disagreed with the heading of the twist
    done: bool = False

    def twist(self) -> tuple[float, float]:
        """The next sub-step's ``linear.x`` [m/s], ``angular.z`` [rad/s]."""
        v, w, clipped = unicycle_twist(self.heading, self.u, self.limits)
        self.sent = (v, w)
        self.saturated += int(clipped[0])
        return float(v[0]), float(w[0])

    def on_pose(self, centre: list[float], yaw: float, stamp_ns: int) -> tuple[float, float] | None:
        """Take a pose (axle centre [m], yaw [rad]): the next twist, or None at the epoch's end
        or for a pose already answered."""
        if self.done or self.sent is None or stamp_ns <= self.last_ns:
            return None
        look = self.limits[2]
        dt = substep_s(self.period_s, self.limits)
        _, expected, _ = unicycle_substep(self.p, self.heading, *self.sent, dt, look)
        heading, agrees = confirmed_heading(float(expected[0]), yaw)
        self.yaw_taken += not agrees
        self.heading = np.array([heading])
        self.p = lookahead_point(np.array([centre]), self.heading, look)
        self.last_ns = stamp_ns
        if stamp_ns >= self.end_ns:
            self.done = True
            return None
        return self.twist()

    def result(self) -> tuple[list[float], float, int]:
        """``x[k+1]`` [m], ``θ[k+1]`` wrapped to ``[−π, π)`` [rad], the epoch's clipped sub-steps."""
        return [float(c) for c in self.p[0]], float(wrap_angle(self.heading)[0]), self.saturated


__all__ = [
    "POINT_AGREES_M",
    "YAW_AGREES_RAD",
    "InnerLoop",
    "confirmed_heading",
    "confirmed_pose",
    "pose_point",
]
