"""What Linux's ``/proc`` says of a benchmarked process: its CPU time and its peak memory."""

from __future__ import annotations

import contextlib
import os
import re
from pathlib import Path

TICK_S = os.sysconf("SC_CLK_TCK")  # clock ticks per second of /proc/<pid>/stat


def cpu_s(pid: int) -> float | None:
    """User + system CPU time of ``pid`` so far [s]; None once the process is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / TICK_S  # utime, stime


def thread_cpu_s(pid: int) -> float:
    """CPU time of ``pid``'s live threads so far [s], to the nanosecond (``schedstat``)."""
    return sum(thread_cpu_by_name(pid).values())


def thread_cpu_by_name(pid: int) -> dict[str, float]:
    """CPU time of ``pid``'s live threads so far [s], summed by name less its number: Zenoh's
    runtimes (``rx-0`` and ``rx-1`` are ``rx``; ``tx``, ``acc``, ``app``, ``net``) and
    ``python`` for the interpreter's own threads."""
    by_name: dict[str, float] = {}
    for task in Path(f"/proc/{pid}/task").glob("*"):
        with contextlib.suppress(OSError, IndexError, ValueError):  # a thread that ended
            name = re.sub(r"[-_]?\d+$", "", (task / "comm").read_text().strip())
            ns = int((task / "schedstat").read_text().split()[0])
            by_name[name] = by_name.get(name, 0.0) + ns / 1e9
    return by_name


def peak_rss_kib(pid: int) -> int:
    """The peak resident set of ``pid`` (``VmHWM``) [KiB]; 0 once the process is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


__all__ = ["cpu_s", "peak_rss_kib", "thread_cpu_by_name", "thread_cpu_s"]
