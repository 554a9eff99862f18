"""The report's realtime section and the run summary's: modelled losses and misses apart."""

from __future__ import annotations

import json
from pathlib import Path

from recorder.reporting.deadlines import FILE, deadline_lines, read_deadlines
from testbed.cli.deadline_lines import deadline_cells, deadline_notes

SUMMARY = {
    "packets_sent": 10000,
    "modelled_losses": {"total": 300, "dropped": 290, "delayed_past_deadline": 10},
    "deadline_misses": {
        "total": 20,
        "by_cause": {"late_sender": 5, "late_netem": 10, "late_leader": 3, "scheduling": 2},
    },
    "delivered_in_time": 9680,
    "unaccounted": 0,
    "deadline_miss_rate": 0.002,
    "deadline_warning": "warning: 20 packets (0.20 %) missed their deadline",
}


def test_the_report_shows_modelled_losses_and_misses_apart_and_warns_above_a_thousandth(
    tmp_path: Path,
) -> None:
    (tmp_path / FILE).write_text(json.dumps(SUMMARY))
    d = read_deadlines(tmp_path)
    assert d is not None
    lines = deadline_lines("run", d)
    assert "modelled losses 300 (3.00 %)" in lines[0]
    assert "deadline misses of the testbed's own making 20 (0.20 %)" in lines[0]
    assert "late_netem 10" in lines[0] and "delivered in time 9680" in lines[0]
    assert len(lines) == 2 and "warning" in lines[1]
    assert "hypervisor" not in lines[1]  # no steal in the file: none said
    d["misses"] = 10
    assert len(deadline_lines("run", d)) == 1  # 0.1 %: no warning
    (tmp_path / FILE).write_text(json.dumps({**SUMMARY, "cpu_steal": 0.052}))
    stolen = read_deadlines(tmp_path)
    assert stolen is not None and stolen["cpu_steal"] == 0.052
    assert "the hypervisor took 5.2 % of the machine's CPU" in deadline_lines("run", stolen)[1]


def test_a_missing_or_forged_accounting_file_is_none_or_skipped_with_a_note(
    tmp_path: Path,
) -> None:
    assert read_deadlines(tmp_path) is None
    (tmp_path / FILE).write_text('{"packets_sent": "lots"}')
    d = read_deadlines(tmp_path)
    assert d is not None and FILE in d["unreadable"]
    assert "skipped, not trusted" in deadline_lines("run", d)[0]


def test_the_run_summary_gives_both_columns_the_causes_and_the_warning() -> None:
    assert deadline_cells(SUMMARY) == ["300 (3.00 %)", "20 (0.20 %)"]
    notes = deadline_notes("estimate", SUMMARY)
    assert notes[0] == (
        "estimate: deadline misses by cause: late_sender 5, late_netem 10, late_leader 3, "
        "scheduling 2"
    )
    assert notes[1].startswith("estimate: warning")
    assert deadline_notes("estimate", {**SUMMARY, "deadline_warning": None}) == notes[:1]
    assert deadline_cells({"deadline_miss_rate": None}) == ["-", "-"]


def test_a_silent_robots_packets_are_a_line_of_their_own_in_the_report_and_the_summary(
    tmp_path: Path,
) -> None:
    (tmp_path / FILE).write_text(json.dumps({**SUMMARY, "robot_silent": 80}))
    d = read_deadlines(tmp_path)
    assert d is not None and d["robot_silent"] == 80 and d["misses"] == 20
    (line,) = [x for x in deadline_lines("run", d) if "robot" in x]
    assert line == (
        "- run: late or never taken as agents waited for their robots' poses (robot silent, "
        "not counted as misses): 80 (0.80 %)"
    )
    notes = deadline_notes("hold", {**SUMMARY, "robot_silent": 80})
    assert (
        "hold: 80 packets late or never taken as agents waited for their robots' poses "
        "(robot silent): the robots', not the testbed's misses"
    ) in notes
    assert not [x for x in deadline_notes("hold", SUMMARY) if "robot" in x]
