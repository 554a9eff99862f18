"""What the air model takes (a phase's frames) and what it gives back (each frame's fate).

A frame is one MAC service data unit: its sender, its receiver (``BROADCAST`` for every
agent), its payload's bytes (the MAC header and FCS are added) and when it is ready to send,
in nanoseconds from the phase's start. Agents are numbered ``0 .. n−1`` by their row of the
positions. The fate is per frame and receiver: delivered or not, when, and why not
(``Cause``).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np
import numpy.typing as npt

from formation.errors import TestbedError

Ints = npt.NDArray[np.int64]
BROADCAST = -1


class Cause(IntEnum):
    """A frame's fate at one receiver."""

    DELIVERED = 0
    COLLISION = 1  # the signal alone would do; overlapping frames (or a busy receiver) did not
    BELOW_SENSITIVITY = 2  # too weak even on a silent channel
    RETRY_LIMIT = 3  # unicast: every attempt failed
    LATE = 4  # received after the phase's end
    NOT_ADDRESSED = 5  # the sender itself, or not a unicast frame's receiver


class AirError(TestbedError):
    """Frames the air model cannot take: names the field, the frame and the value."""

    def __init__(self, field: str, index: int, value: object, problem: str) -> None:
        self.field, self.index, self.value, self.problem = field, index, value, problem
        super().__init__(f"frames.{field}[{index}] = {value!r}; {problem}")


@dataclass(frozen=True)
class Frames:
    """A phase's frames, one entry per frame; ``check`` holds them to ``n`` agents."""

    sender: Ints
    receiver: Ints  # BROADCAST (-1) or an agent
    payload_bytes: Ints  # [B] the MSDU
    ready_ns: Ints  # [ns] from the phase's start

    @classmethod
    def of(
        cls,
        sender: npt.ArrayLike,
        receiver: npt.ArrayLike,
        payload_bytes: npt.ArrayLike,
        ready_ns: npt.ArrayLike,
    ) -> Frames:
        arrays = [np.atleast_1d(np.asarray(a, dtype=np.int64)) for a in (sender, receiver)]
        sizes = np.atleast_1d(np.asarray(payload_bytes, dtype=np.int64))
        ready = np.atleast_1d(np.asarray(ready_ns, dtype=np.int64))
        m = max(a.shape[0] for a in (*arrays, sizes, ready))
        return cls(*(np.broadcast_to(a, (m,)).copy() for a in (*arrays, sizes, ready)))

    def __len__(self) -> int:
        return int(self.sender.shape[0])

    def check(self, n: int) -> None:
        """An ``AirError`` for the first frame that does not fit a team of ``n``."""
        rules = [
            ("sender", (self.sender < 0) | (self.sender >= n), f"expected an agent 0..{n - 1}"),
            (
                "receiver",
                (self.receiver < BROADCAST) | (self.receiver >= n) | (self.receiver == self.sender),
                f"expected another agent 0..{n - 1} or {BROADCAST} (broadcast)",
            ),
            ("payload_bytes", self.payload_bytes < 0, "expected ≥ 0"),
            ("ready_ns", self.ready_ns < 0, "expected ≥ 0 (ns from the phase's start)"),
        ]
        for field, bad, problem in rules:
            if bad.any():
                k = int(np.argmax(bad))
                raise AirError(field, k, int(getattr(self, field)[k]), problem)


@dataclass(frozen=True)
class PhaseOutcome:
    """Each frame's fate at each agent: arrays of shape (frames, agents) and (frames,)."""

    delivered: npt.NDArray[np.bool_]
    arrival_ns: Ints  # [ns] from the phase's start; -1 where not delivered
    cause: npt.NDArray[np.int8]  # Cause codes
    attempts: Ints  # transmissions of each frame
    first_start_ns: Ints  # [ns] when each frame first took the air
    end_ns: int  # [ns] when the medium fell silent

    def at(self, frame: int, receiver: int) -> Cause:
        return Cause(int(self.cause[frame, receiver]))


__all__ = ["BROADCAST", "AirError", "Cause", "Frames", "PhaseOutcome"]
