"""Realtime deadline misses by cause: which part of the testbed made a packet late.

A packet that missed its phase's deadline (docs/architecture.md "Time") is put down to
the first of, in order:

- ``late_sender`` / ``late_leader``: its sender (an agent, or the leader for estimates)
  published it more than :data:`SLACK` of a period after its phase started;
- ``late_netem``: netem forwarded it after the deadline, though it had it (and its
  model's delay had ended) in time: netem counts these itself (``late_forwards``);
- ``scheduling``: the rest: queued at the receiver in time but taken late, or late on
  the way past netem (the router, the receiver's Zenoh thread).

A late packet its sender marked ``robot_silent`` (its agent waited for its robot's pose, so
sent it late) is the robot's, not the testbed's: counted as :data:`ROBOT_SILENT`, apart from
the misses, their rate and their warning. So are the packets an agent whose robot was lost
had queued and never took.

A receiver first counts a packet neither late sent nor queued in time as ``late_netem``;
:func:`account` then takes netem's ``modelled_late`` (its model delayed the packet past
the deadline: a modelled loss, not a miss) and moves what exceeds ``late_forwards`` to
``scheduling``.

Stamps (``stamp_ns``) are the sender's monotonic clock, turned into wall time with the
receiver's own offset: exact between processes of one host (CLOCK_MONOTONIC is shared).

A run's books (:func:`realtime_accounting`): every packet netem decided is a modelled loss,
a deadline miss or delivered in time, from the counts the receivers and netem put in their
final statuses (:func:`deadline_counts`). This module holds all the counting and the rates;
the report's and the terminal's lines only print them.
"""

from __future__ import annotations

import json
import time
from collections import Counter
from collections.abc import Iterable, Mapping
from typing import Any, NamedTuple

from formation.messages import Status
from formation.realtime import ESTIMATE_DEADLINE, REPORT_DEADLINE, STATE_DEADLINE, Clock

SLACK = 0.10  # of a period: a sender publishing later than this after its phase start is late
WARN_RATE = 0.001  # misses above this share of the packets sent: a warning (issue 18)
# epochs a receiver remembers which packets it used: a copy of one comes within a period, and
# a packet stamped in time that it never used is a scheduling miss (queued after the take)
USED_KEPT = 4
CAUSES = ("late_sender", "late_netem", "late_leader", "scheduling")  # the testbed's own
ROBOT_SILENT = "robot_silent"  # late, or never taken, as an agent waited for its robot
NETEM = "netem."  # the prefix of netem's counts among the run's
PHASES = {  # the phase a packet kind travels in: (start, deadline) as fractions of a period
    "state": (0.0, STATE_DEADLINE),
    "report": (STATE_DEADLINE, REPORT_DEADLINE),
    "estimate": (REPORT_DEADLINE, ESTIMATE_DEADLINE),
}


def wall_of(stamp_ns: int) -> int:
    """A monotonic stamp of a process on this host as ``time.time_ns()`` wall time."""
    return stamp_ns + time.time_ns() - time.monotonic_ns()


def cause(
    clock: Clock,
    kind: str,
    epoch: int,
    stamp_ns: int,
    arrived_ns: int,
    robot_silent: bool = False,
) -> str:
    """The cause of a deadline miss of a ``kind`` packet of ``epoch`` (see the module doc).

    ``stamp_ns``: the sender's monotonic stamp; ``arrived_ns``: wall time it was queued here;
    ``robot_silent``: the sender marked it sent late for its robot's pose.
    """
    start, deadline = PHASES[kind]
    if wall_of(stamp_ns) > clock.at(epoch, start + SLACK):
        if robot_silent:
            return ROBOT_SILENT
        return "late_leader" if kind == "estimate" else "late_sender"
    if arrived_ns <= clock.at(epoch, deadline):
        return "scheduling"
    return "late_netem"


class Accounting(NamedTuple):
    """A run's receivers' packets: taken in time, and missed by cause (netem's modelled apart)."""

    in_time: int
    by_cause: dict[str, int]
    modelled_late: int  # delayed past their deadline by netem's models: modelled losses
    robot_silent: int = 0  # late or never taken as an agent waited for its robot: not misses

    @property
    def misses(self) -> int:
        return sum(self.by_cause.values())


def account(received: Mapping[str, int], netem: Mapping[str, int]) -> Accounting:
    """The run's deadline accounting from the receivers' and netem's counts.

    ``received``: the agents' and the leader's counters (``in_time`` and one per cause);
    ``netem``: its ``modelled_late`` and ``late_forwards`` (see the module doc).
    """
    by_cause = {c: int(received.get(c, 0)) for c in CAUSES}
    modelled = min(int(netem.get("modelled_late", 0)), by_cause["late_netem"])
    on_the_way = by_cause["late_netem"] - modelled
    by_cause["late_netem"] = min(on_the_way, int(netem.get("late_forwards", 0)))
    by_cause["scheduling"] += on_the_way - by_cause["late_netem"]
    silent = int(received.get(ROBOT_SILENT, 0))
    return Accounting(int(received.get("in_time", 0)), by_cause, modelled, silent)


def over_warn_rate(misses: int, sent: int) -> bool:
    """Whether ``misses`` exceed :data:`WARN_RATE` of the ``sent`` packets (a warning)."""
    return misses > WARN_RATE * sent


def deadline_counts(statuses: Iterable[Status]) -> dict[str, int]:
    """The receivers' counts summed, and netem's under :data:`NETEM`; unreadable details skipped."""
    counts: Counter[str] = Counter()
    for st in statuses:
        if st.role not in ("agent", "pool", "leader", "netem") or not st.detail.startswith("{"):
            continue
        try:
            detail = json.loads(st.detail)
            got = {str(k): int(v) for k, v in detail.items()}
        except (ValueError, TypeError, AttributeError):
            continue  # a forged or broken status: its counts are not trusted
        prefix = NETEM if st.role == "netem" else ""
        counts.update({prefix + k: v for k, v in got.items()})
    return dict(counts)


def _queued(netem: Mapping[str, int], modelled_late: int) -> dict[str, int]:
    """Of the modelled losses, the capacity queues' (docs/model.md §9): refused, and held past
    the deadline; none when no queue dropped or held a packet late."""
    if "queue_drops" not in netem and "queue_late" not in netem:
        return {}
    return {
        "queue_dropped": int(netem.get("queue_drops", 0)),
        "queued_past_deadline": min(int(netem.get("queue_late", 0)), modelled_late),
    }


def realtime_accounting(
    counts: Mapping[str, int],
    drops: Mapping[str, tuple[int, int]],
    cpu_steal: float | None = None,
    untaken: int = 0,
) -> dict[str, Any]:
    """Every packet netem decided, as modelled losses, deadline misses or delivered in time.

    ``counts``: :func:`deadline_counts` (none in lockstep: only ``deadline_miss_rate``, None);
    ``drops``: netem's ``link → (sent, dropped)`` by its models. ``unaccounted``: the
    packets none of the three took (e.g. still on their way when the run ended); 0 when
    the books balance. ``robot_silent``: the packets late or never taken as an agent waited
    for its robot's pose, neither misses nor in the rate. ``warning``: a line to print when misses exceed :data:`WARN_RATE`;
    it names ``cpu_steal`` (the hypervisor's share of the CPU during the run) when some was
    taken: on a shared VM that, more than the testbed, made the misses. ``untaken``: packets
    delivered to agents whose robots were lost, of the epochs they never took (robot silent).
    """
    if not counts:
        return {"deadline_miss_rate": None}
    sent, dropped = sum(s for s, _ in drops.values()), sum(d for _, d in drops.values())
    netem = {k.removeprefix(NETEM): v for k, v in counts.items() if k.startswith(NETEM)}
    got = account({k: v for k, v in counts.items() if not k.startswith(NETEM)}, netem)
    got = got._replace(robot_silent=got.robot_silent + untaken)
    misses = {"total": got.misses, "by_cause": got.by_cause}
    modelled = dropped + got.modelled_late
    rate = got.misses / sent if sent else None
    warning = None
    if rate is not None and over_warn_rate(got.misses, sent):
        causes = ", ".join(f"{c} {n}" for c, n in got.by_cause.items() if n)
        warning = (
            f"warning: {got.misses} packets ({100 * rate:.2f} %) missed their deadline "
            f"of the testbed's own making ({causes}), above {100 * WARN_RATE:g} %: "
            f"this run cannot tell modelled losses of that size from the testbed's"
        )
        if cpu_steal:
            warning += (
                f"; the hypervisor took {100 * cpu_steal:.1f} % of this machine's CPU meanwhile "
                "(steal): its stalls count as misses"
            )
    return {
        "deadline_misses": misses,
        "modelled_losses": {
            "total": modelled,
            "dropped": dropped,
            "delayed_past_deadline": got.modelled_late,
            **_queued(netem, got.modelled_late),
        },
        "delivered_in_time": got.in_time,
        ROBOT_SILENT: got.robot_silent,
        "unaccounted": sent - modelled - got.misses - got.in_time - got.robot_silent,
        "deadline_miss_rate": rate,
        "deadline_warning": warning,
    }
