"""Realtime runs: the stages every packet passes run ahead of the agents, where allowed.

Each packet crosses the router and netem, and every estimate comes from the leader: one
late wake-up of theirs makes every agent's packet late, while a late agent delays only its
own. So in realtime the launcher lowers their nice value (:data:`SHARED_NICE`), which needs
root or ``CAP_SYS_NICE``; without it the priorities stay as they are, and the run says so.
"""

from __future__ import annotations

import os
from collections.abc import Mapping

SHARED_NICE = -10
SHARED = ("router", "netem", "leader")  # every packet's path, in the order it crosses them


def favour_shared(pids: Mapping[str, int]) -> str:
    """Lower the nice value of the processes named in :data:`SHARED`; what was done, as a line."""
    try:
        for name in SHARED:
            if name in pids:
                os.setpriority(os.PRIO_PROCESS, pids[name], SHARED_NICE)
    except PermissionError:
        return "priorities unchanged (a nice value below 0 needs root or CAP_SYS_NICE)"
    except ProcessLookupError:
        return "priorities unchanged (a process had already ended)"
    return f"router, netem and leader at nice {SHARED_NICE}, ahead of the agents"


__all__ = ["SHARED", "SHARED_NICE", "favour_shared"]
