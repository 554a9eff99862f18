"""The robots' poses as recorded (``body/<i>/pose/<type>``, docs/robots.md "In the recording"):
where the robots were, beside where their agents meant them to be.

In realtime an agent records, at its step of epoch ``k``, the newest pose it stepped from: the
robot's measured ``x[k]``, with the record's ``sequence`` ``k`` (a restarted or joining agent's
too, from its first epoch). In lockstep the agent's state is the pose itself
(it places ``x[k+1]`` from the pose stamped ``k + 1``), so the states already are the poses.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt
from mcap.records import Message

from formation import keys
from formation.scenario import Scenario
from recorder.reading.decoder import DecodeError, decode_cdr

Array = npt.NDArray[np.float64]


class RecordedPoses:
    """Each robot's recorded poses: (agent, epoch) → (x, y, z) [robot m] and yaw [rad]."""

    def __init__(self) -> None:
        self.poses: dict[tuple[int, int], tuple[tuple[float, float, float], float]] = {}

    def add(self, topic: str, record: Message, type_name: str) -> None:
        """One trusted pose record (the trust gate has checked its owner and its CDR)."""
        parsed = keys.parse(topic)
        if len(parsed.args) < 2 or parsed.args[1] != "pose":
            return
        try:
            msg = decode_cdr(type_name, record.data)
        except DecodeError:
            return  # counted by the gate already
        self.poses[int(parsed.args[0]), record.sequence] = pose_of(msg)

    def measured(self, scenario: Scenario, count: int) -> Array | None:
        """(count, n, d) the robots' positions as their agents' states measure them [scenario
        m]: the pose over ``scale``, a unicycle's look-ahead point; NaN where none was recorded.
        None in lockstep (the states are the poses) or without a pose."""
        if scenario.runtime.mode != "realtime" or not self.poses:
            return None
        n, d = scenario.n, scenario.dimension
        out = np.full((count, n, d), np.nan)
        for (i, k), (xyz, yaw) in self.poses.items():
            if 1 <= i <= n and 0 <= k < count:
                out[k, i - 1] = measured_point(scenario, xyz, yaw)
        return out


def measured_point(scenario: Scenario, xyz: tuple[float, float, float], yaw: float) -> list[float]:
    """A pose [robot m] as its agent's state measures it [scenario m]: over ``scale``, a
    unicycle's look-ahead point."""
    p = [c / scenario.body.scale for c in xyz[: scenario.dimension]]
    if scenario.control.dynamics == "unicycle":
        lookahead = scenario.control.unicycle.lookahead_m
        p = [p[0] + lookahead * math.cos(yaw), p[1] + lookahead * math.sin(yaw)]
    return p


def pose_of(msg: Any) -> tuple[tuple[float, float, float], float]:
    """A decoded ``PoseStamped`` or ``Odometry``: its position [robot m] and yaw [rad]."""
    pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose  # Odometry, PoseStamped
    p, q = pose.position, pose.orientation
    yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
    return (float(p.x), float(p.y), float(p.z)), yaw


__all__ = ["RecordedPoses", "measured_point", "pose_of"]
