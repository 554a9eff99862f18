"""A realtime run's books: modelled losses + deadline misses + in time = sent."""

from __future__ import annotations

import json

from formation import deadline_counts, realtime_accounting
from formation.messages import Status


def status(role: str, detail: str) -> Status:
    return Status(run_id="r", sender=role, seq=0, epoch=9, stamp_ns=1, role=role, state="done",
                  detail=detail)  # fmt: skip


def counts(**kw: int) -> str:
    return json.dumps({"in_time": 0, "late_sender": 0, "late_netem": 0, "late_leader": 0,
                       "scheduling": 0, **kw})  # fmt: skip


def test_receivers_counts_are_summed_netems_kept_apart_and_unreadable_ones_skipped() -> None:
    got = deadline_counts([
        status("agent", counts(in_time=10, late_netem=2)),
        status("pool", counts(in_time=20, scheduling=1)),
        status("leader", counts(in_time=5, late_sender=1)),
        status("netem", json.dumps({"modelled_late": 1})),
        status("agent", '{"in_time": "many"}'),  # forged: not trusted
        status("agent", "[1, 2]"),
        status("agent", '{"in_time": 3'),
        status("recorder", counts(in_time=99)),  # not a receiver of packets
    ])  # fmt: skip
    assert got["in_time"] == 35 and got["late_netem"] == 2 and got["scheduling"] == 1
    assert got["late_sender"] == 1 and got["netem.modelled_late"] == 1
    assert "modelled_late" not in got


def test_the_books_balance_and_modelled_losses_stand_apart_from_misses() -> None:
    c = deadline_counts([
        status("agent", counts(in_time=85, late_netem=3, scheduling=1)),
        status("leader", counts(late_leader=1)),
        status("netem", json.dumps({"modelled_late": 2, "late_forwards": 1})),
    ])  # fmt: skip
    got = realtime_accounting(c, {"1->2": (60, 6), "2->1": (40, 2)})
    assert got["modelled_losses"] == {"total": 10, "dropped": 8, "delayed_past_deadline": 2}
    assert got["deadline_misses"] == {
        "total": 3,
        "by_cause": {"late_sender": 0, "late_netem": 1, "late_leader": 1, "scheduling": 1},
    }
    assert got["delivered_in_time"] == 85
    assert got["unaccounted"] == 2
    assert got["deadline_miss_rate"] == 0.03
    assert "3 packets (3.00 %)" in got["deadline_warning"]


def test_no_warning_at_or_below_a_thousandth_and_none_in_lockstep() -> None:
    c = deadline_counts([status("agent", counts(in_time=999, late_netem=1))])
    got = realtime_accounting(c, {"1->2": (1000, 0)})
    assert got["deadline_miss_rate"] == 0.001 and got["deadline_warning"] is None
    assert got["unaccounted"] == 0
    assert realtime_accounting({}, {"1->2": (1000, 0)}) == {"deadline_miss_rate": None}


def test_the_warning_names_the_hypervisors_steal_when_some_was_taken() -> None:
    c = deadline_counts([status("agent", counts(in_time=95, scheduling=5))])
    stolen = realtime_accounting(c, {"1->2": (100, 0)}, cpu_steal=0.071)
    assert "the hypervisor took 7.1 % of this machine's CPU meanwhile" in stolen["deadline_warning"]
    for none in (0.0, None):
        assert (
            "hypervisor" not in realtime_accounting(c, {"1->2": (100, 0)}, none)["deadline_warning"]
        )
