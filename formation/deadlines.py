"""Realtime deadline misses by cause: which part of the testbed made a packet late.

A packet that missed its phase's deadline (docs/architecture.md "Time") is put down to
the first of, in order:

- ``late_sender`` / ``late_leader``: its sender (an agent, or the leader for estimates)
  published it more than :data:`SLACK` of a period after its phase started;
- ``late_netem``: netem forwarded it after the deadline, though it had it (and its
  model's delay had ended) in time: netem counts these itself (``late_forwards``);
- ``scheduling``: the rest: queued at the receiver in time but taken late, or late on
  the way past netem (the router, the receiver's Zenoh thread).

A receiver first counts a packet neither late sent nor queued in time as ``late_netem``;
:func:`summarise` then takes netem's ``modelled_late`` (its model delayed the packet past
the deadline: a modelled loss, not a miss) and moves what exceeds ``late_forwards`` to
``scheduling``.

Stamps (``stamp_ns``) are the sender's monotonic clock, turned into wall time with the
receiver's own offset: exact between processes of one host (CLOCK_MONOTONIC is shared).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import NamedTuple

from formation.realtime import ESTIMATE_DEADLINE, REPORT_DEADLINE, STATE_DEADLINE, Clock

SLACK = 0.10  # of a period: a sender publishing later than this after its phase start is late
WARN_RATE = 0.001  # misses above this share of the packets sent: a warning (issue 18)
CAUSES = ("late_sender", "late_netem", "late_leader", "scheduling")
PHASES = {  # the phase a packet kind travels in: (start, deadline) as fractions of a period
    "state": (0.0, STATE_DEADLINE),
    "report": (STATE_DEADLINE, REPORT_DEADLINE),
    "estimate": (REPORT_DEADLINE, ESTIMATE_DEADLINE),
}


def wall_of(stamp_ns: int) -> int:
    """A monotonic stamp of a process on this host as ``time.time_ns()`` wall time."""
    return stamp_ns + time.time_ns() - time.monotonic_ns()


def cause(clock: Clock, kind: str, epoch: int, stamp_ns: int, arrived_ns: int) -> str:
    """The cause of a deadline miss of a ``kind`` packet of ``epoch`` (see the module doc).

    ``stamp_ns``: the sender's monotonic stamp; ``arrived_ns``: wall time it was queued here.
    """
    start, deadline = PHASES[kind]
    if wall_of(stamp_ns) > clock.at(epoch, start + SLACK):
        return "late_leader" if kind == "estimate" else "late_sender"
    if arrived_ns <= clock.at(epoch, deadline):
        return "scheduling"
    return "late_netem"


class Accounting(NamedTuple):
    """A run's receivers' packets: taken in time, and missed by cause (netem's modelled apart)."""

    in_time: int
    by_cause: dict[str, int]
    modelled_late: int  # delayed past their deadline by netem's models: modelled losses

    @property
    def misses(self) -> int:
        return sum(self.by_cause.values())


def summarise(received: Mapping[str, int], netem: Mapping[str, int]) -> Accounting:
    """The run's deadline accounting from the receivers' and netem's counts.

    ``received``: the agents' and the leader's counters (``in_time`` and one per cause);
    ``netem``: its ``modelled_late`` and ``late_forwards`` (see the module doc).
    """
    by_cause = {c: int(received.get(c, 0)) for c in CAUSES}
    modelled = min(int(netem.get("modelled_late", 0)), by_cause["late_netem"])
    on_the_way = by_cause["late_netem"] - modelled
    by_cause["late_netem"] = min(on_the_way, int(netem.get("late_forwards", 0)))
    by_cause["scheduling"] += on_the_way - by_cause["late_netem"]
    return Accounting(int(received.get("in_time", 0)), by_cause, modelled)
