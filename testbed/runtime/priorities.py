"""Realtime runs: the stages every packet passes run ahead of the agents, where allowed.

Each packet crosses the router and netem, and every estimate comes from the leader: one
late wake-up of theirs makes every agent's packet late, while a late agent delays only its
own. So in realtime the launcher lowers their nice value (:data:`SHARED_NICE`), which needs
root or ``CAP_SYS_NICE``; without it the priorities stay as they are, and the run says so.

Linux keeps a nice value per thread, and ``setpriority`` on a pid sets its main thread's
only: the router's work runs on Zenoh's threads, started before the launcher gets to it.
So every thread of the process is set (a thread started later inherits its creator's).

A real-time class (``SCHED_RR``) for these threads was tried and is not used: their CPU
per epoch doubled and misses rose (bench_realtime --quick, seed 1, three interleaved
rounds: 20 processes at 20 Hz 9.6-26.8 % against 5.0-10.0 % with nice alone).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

SHARED_NICE = -10
SHARED = ("router", "netem", "leader")  # every packet's path, in the order it crosses them


def threads(pid: int) -> list[int]:
    """The thread ids of process ``pid`` (empty once it has ended)."""
    try:
        return sorted(int(t) for t in os.listdir(Path("/proc") / str(pid) / "task"))
    except OSError:
        return []


def favour_shared(pids: Mapping[str, int]) -> str:
    """Lower the nice value of every thread of the processes named in :data:`SHARED`; what
    was done, as a line."""
    try:
        for name in SHARED:
            if name in pids:
                for tid in threads(pids[name]) or [pids[name]]:
                    os.setpriority(os.PRIO_PROCESS, tid, SHARED_NICE)
    except PermissionError:
        return "priorities unchanged (a nice value below 0 needs root or CAP_SYS_NICE)"
    except ProcessLookupError:
        return "priorities unchanged (a process had already ended)"
    return f"router, netem and leader at nice {SHARED_NICE}, ahead of the agents"


__all__ = ["SHARED", "SHARED_NICE", "favour_shared", "threads"]
