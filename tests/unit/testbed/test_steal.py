"""The hypervisor's share of the CPU (steal), read from /proc/stat."""

from __future__ import annotations

from pathlib import Path

from testbed.runtime import steal

# user nice system idle iowait irq softirq steal guest guest_nice
STAT = "cpu  {user} 10 300 {idle} 50 0 20 {steal} 7 0\ncpu0  1 2 3 4 5 6 7 8 0 0\n"


def test_it_reads_the_machines_ticks_and_the_share_stolen_between_two_readings(
    tmp_path: Path,
) -> None:
    path = tmp_path / "stat"
    path.write_text(STAT.format(user=1000, idle=8000, steal=20))
    before = steal.ticks(path)
    assert before == steal.Ticks(1000 + 10 + 300 + 8000 + 50 + 0 + 20 + 20, 20)  # not guest
    path.write_text(STAT.format(user=1600, idle=8300, steal=120))
    after = steal.ticks(path)
    assert after is not None and after.total - before.total == 1000
    assert steal.share(before, after) == 0.1


def test_no_reading_where_there_is_no_proc_stat(tmp_path: Path) -> None:
    assert steal.ticks(tmp_path / "absent") is None
    (tmp_path / "odd").write_text("intr 1 2 3\n")
    assert steal.ticks(tmp_path / "odd") is None
    assert steal.share(None, steal.Ticks(10, 1)) is None
    assert steal.share(steal.Ticks(10, 1), steal.Ticks(10, 1)) is None  # no time passed


def test_this_machine_has_a_reading() -> None:
    got = steal.ticks()
    assert got is not None and got.total > 0 and 0 <= got.steal <= got.total
