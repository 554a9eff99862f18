"""How much of this machine's CPU its hypervisor took (steal time), from ``/proc/stat``.

On a shared VM a realtime run's misses follow steal more than anything of the testbed's:
20 agent processes at 20 Hz (seed 1) missed 0.00-0.04 % of their deadlines at 0.1 % steal
and 28-42 % at 7-12 % (bench_realtime). So a run's summary says how much was taken.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

PROC_STAT = Path("/proc/stat")


class Ticks(NamedTuple):
    """CPU time of every core so far, in clock ticks: all of it, and what was stolen."""

    total: int
    steal: int


def ticks(proc_stat: Path = PROC_STAT) -> Ticks | None:
    """This machine's CPU ticks so far; None where there is no ``/proc/stat`` (not Linux)."""
    try:
        line = proc_stat.read_text().split("\n", 1)[0].split()
    except OSError:
        return None
    if len(line) < 9 or line[0] != "cpu":
        return None
    fields = [int(f) for f in line[1:]]
    return Ticks(sum(fields[:8]), fields[7])  # user … steal; guest time is within user's


def share(before: Ticks | None, after: Ticks | None) -> float | None:
    """The share of the CPU stolen between two readings (0..1); None if either is missing."""
    if before is None or after is None or after.total <= before.total:
        return None
    return (after.steal - before.steal) / (after.total - before.total)


__all__ = ["Ticks", "share", "ticks"]
