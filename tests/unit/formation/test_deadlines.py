"""Deadline misses by cause (formation.deadlines): the first cause that fits, in order."""

from __future__ import annotations

import time

import pytest

from formation.deadlines import ROBOT_SILENT, SLACK, account, cause, realtime_accounting
from formation.realtime import REPORT_DEADLINE, STATE_DEADLINE, Clock

CLOCK = Clock(t0_ns=time.time_ns(), period_ns=50_000_000)
OFFSET = time.time_ns() - time.monotonic_ns()  # wall time of a monotonic stamp, on this host


def stamp(wall_ns: int) -> int:
    return wall_ns - OFFSET


@pytest.mark.parametrize(
    ("kind", "start"), [("state", 0.0), ("report", STATE_DEADLINE), ("estimate", REPORT_DEADLINE)]
)
def test_a_packet_sent_after_its_phase_start_and_the_slack_is_the_senders(
    kind: str, start: float
) -> None:
    late = stamp(CLOCK.at(3, start + SLACK + 0.05))
    arrived = CLOCK.at(3, 0.99)
    expected = "late_leader" if kind == "estimate" else "late_sender"
    assert cause(CLOCK, kind, 3, late, arrived) == expected


def test_sent_in_time_and_queued_by_the_deadline_is_the_receivers_scheduling() -> None:
    sent = stamp(CLOCK.at(3, 0.01))
    assert cause(CLOCK, "state", 3, sent, CLOCK.at(3, STATE_DEADLINE - 0.01)) == "scheduling"


def test_sent_in_time_and_queued_after_the_deadline_was_late_on_the_way() -> None:
    sent = stamp(CLOCK.at(3, 0.01))
    assert cause(CLOCK, "state", 3, sent, CLOCK.at(3, STATE_DEADLINE + 0.01)) == "late_netem"
    assert cause(CLOCK, "report", 3, stamp(CLOCK.at(3, STATE_DEADLINE + 0.02)),
                 CLOCK.at(3, REPORT_DEADLINE + 0.01)) == "late_netem"  # fmt: skip


def test_netems_modelled_delays_are_taken_from_late_netem_never_below_zero() -> None:
    got = account({"in_time": 90, "late_sender": 2, "late_netem": 5, "late_leader": 1,
                     "scheduling": 0, "packets": 80}, {"modelled_late": 3, "late_forwards": 9})  # fmt: skip
    assert got.in_time == 90 and got.modelled_late == 3
    assert got.by_cause == {"late_sender": 2, "late_netem": 2, "late_leader": 1, "scheduling": 0}
    assert got.misses == 5
    assert account({"late_netem": 1}, {"modelled_late": 4}).modelled_late == 1


def test_late_on_the_way_beyond_netems_own_late_forwards_is_scheduling() -> None:
    got = account({"late_netem": 10, "scheduling": 1}, {"modelled_late": 2, "late_forwards": 3})
    assert got.by_cause == {"late_sender": 0, "late_netem": 3, "late_leader": 0, "scheduling": 6}
    assert got.misses == 9 and got.modelled_late == 2


def test_a_late_packet_sent_for_a_silent_robot_is_the_robots_and_an_in_time_one_is_not() -> None:
    late = stamp(CLOCK.at(3, STATE_DEADLINE + SLACK + 0.05))
    arrived = CLOCK.at(3, 0.99)
    assert cause(CLOCK, "report", 3, late, arrived, robot_silent=True) == ROBOT_SILENT
    sent = stamp(CLOCK.at(3, 0.01))  # the mark does not excuse a packet late on the way
    late_on_the_way = CLOCK.at(3, STATE_DEADLINE + 0.01)
    assert cause(CLOCK, "state", 3, sent, late_on_the_way, robot_silent=True) == "late_netem"


def test_a_silent_robots_packets_are_neither_misses_nor_in_the_rate_nor_warned_of() -> None:
    counts = {"in_time": 900, "late_sender": 1, ROBOT_SILENT: 60}
    got = realtime_accounting(counts, {"1->2": (1000, 20)}, untaken=19)
    assert got["deadline_misses"] == {
        "total": 1,
        "by_cause": {"late_sender": 1, "late_netem": 0, "late_leader": 0, "scheduling": 0},
    }
    assert got["robot_silent"] == 79 and got["unaccounted"] == 0
    assert got["deadline_miss_rate"] == 0.001 and got["deadline_warning"] is None
