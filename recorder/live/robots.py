"""The live view's robots: each measured pose the agents record (``body/<i>/pose/<type>``,
docs/robots.md "In the recording") drawn as an entity of its own beside the agents' states,
and each robot's tracking error (its pose against its agent's state of that epoch) as a
``foxglove.Log`` line, a warning above ``body.tracking_warning_m``.

Realtime only: in lockstep an agent's state is its robot's pose. The ``k``-th pose on a
robot's channel is its measured ``x[k]`` (the agent records one per step), so the epoch
comes from the order the poses came in, as :class:`recorder.reading.bodies.RecordedPoses`
takes it from the record's sequence. Pure: payloads in, ``(key, payload)`` out.
"""

from __future__ import annotations

import math
from collections import Counter

from foxglove.messages import Log, LogLevel

from formation import keys
from formation.body import POSE_TYPES
from formation.scenario import Scenario
from recorder.live.scene import robot_entity, timestamp
from recorder.reading.bodies import measured_point, pose_of
from recorder.reading.decoder import DecodeError, decode_cdr
from recorder.recording.schemas import ROS2

KEPT_EPOCHS = 8  # an agent's states kept for its robot's pose, which comes a step later
POSE_KINDS = tuple(ROS2 + t for t in POSE_TYPES)  # the channel kinds of the robots' poses
Derived = tuple[str, bytes]


class LiveRobots:
    """Each robot's measured pose as a scene entity ``robot <i>`` and a tracking log line."""

    def __init__(self, scenario: Scenario, run_id: str) -> None:
        self.scenario, self.run_id = scenario, run_id
        self.active = scenario.runtime.mode == "realtime" and scenario.body.kind != "simulated"
        self._count: Counter[int] = Counter()  # poses seen per robot: the next one's epoch
        self._intended: dict[int, dict[int, list[float]]] = {}  # agent → epoch → x_i[k] [m]

    def on_state(self, agent: int, epoch: int, position: list[float]) -> None:
        """Agent ``agent``'s state of ``epoch``: where it meant its robot to be [m]."""
        if self.active:
            kept = self._intended.setdefault(agent, {})
            kept[epoch] = position
            for k in [k for k in kept if k < epoch - KEPT_EPOCHS]:
                del kept[k]

    def on_pose(self, key: str, payload: bytes, stamp_ns: int) -> list[Derived]:
        """A robot's recorded pose: its entity in the scene, its tracking error in the log."""
        args = keys.parse(key).args
        if not self.active or len(args) < 3 or args[1] != "pose":
            return []
        try:
            i, msg = int(args[0]), decode_cdr("/".join(args[2:]), payload)
        except (ValueError, DecodeError):
            return []  # the trust gate counts it
        if not 1 <= i <= self.scenario.n:
            return []
        k = self._count[i]
        self._count[i] += 1
        point = measured_point(self.scenario, *pose_of(msg))
        if not all(math.isfinite(c) for c in point):
            return []
        intended = self._intended.get(i, {}).get(k)
        error = None if intended is None else math.dist(point, intended)
        scene = robot_entity(i, k, point, stamp_ns)
        return [(keys.scene(self.run_id), scene.encode()), self._log(i, k, point, error, stamp_ns)]

    def _log(
        self, i: int, k: int, point: list[float], error: float | None, stamp_ns: int
    ) -> Derived:
        where = ", ".join(f"{c:.4g}" for c in point)
        text = f"epoch {k}: robot {i} measured at ({where}) m"
        level = LogLevel.Info
        if error is not None:
            text += f", tracking error {error:.4g} m (its pose against its agent's state)"
            if error > self.scenario.body.tracking_warning_m:
                level = LogLevel.Warning
        log = Log(timestamp=timestamp(stamp_ns), level=level, message=text, name=f"robot/{i}")
        return keys.log(self.run_id), log.encode()


__all__ = ["POSE_KINDS", "LiveRobots"]
