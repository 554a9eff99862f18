"""Realtime: the router, netem and the leader get ahead of the agents where the OS allows it."""

from __future__ import annotations

import os
import subprocess
import sys

from testbed.runtime.priorities import SHARED_NICE, favour_shared


def test_the_shared_stages_are_lowered_where_allowed_and_others_left_alone() -> None:
    procs = [
        subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"]) for _ in range(2)
    ]
    try:
        netem, agent = (p.pid for p in procs)
        before = os.getpriority(os.PRIO_PROCESS, agent)
        line = favour_shared({"netem": netem, "agent-1": agent})
        if line.startswith("priorities unchanged"):
            assert os.getpriority(os.PRIO_PROCESS, netem) == before
        else:
            assert os.getpriority(os.PRIO_PROCESS, netem) == SHARED_NICE
            assert str(SHARED_NICE) in line
        assert os.getpriority(os.PRIO_PROCESS, agent) == before, "agents keep theirs"
    finally:
        for p in procs:
            p.kill()
            p.wait()


def test_a_process_already_gone_is_said() -> None:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    assert favour_shared({"leader": p.pid}).startswith("priorities unchanged")
