"""Realtime: the router, netem and the leader get ahead of the agents where the OS allows it."""

from __future__ import annotations

import os
import subprocess
import sys

from testbed.runtime.priorities import SHARED_NICE, favour_shared, threads

# A process with a second thread already running, as the router's Zenoh threads are.
WITH_A_THREAD = "import threading, time; threading.Thread(target=time.sleep, args=(30,)).start(); print(flush=True); time.sleep(30)"


def test_the_shared_stages_are_lowered_where_allowed_and_others_left_alone() -> None:
    procs = [
        subprocess.Popen([sys.executable, "-c", WITH_A_THREAD], stdout=subprocess.PIPE)
        for _ in range(2)
    ]
    try:
        for p in procs:  # its second thread is running once it prints
            assert p.stdout is not None and p.stdout.readline() == b"\n"
        netem, agent = (p.pid for p in procs)
        assert len(threads(netem)) == 2
        before = os.getpriority(os.PRIO_PROCESS, agent)
        line = favour_shared({"netem": netem, "agent-1": agent})
        expected = before if line.startswith("priorities unchanged") else SHARED_NICE
        # every thread, not only the main one (setpriority on a pid sets that thread's)
        assert [os.getpriority(os.PRIO_PROCESS, t) for t in threads(netem)] == [expected] * 2
        if expected == SHARED_NICE:
            assert str(SHARED_NICE) in line
        assert {os.getpriority(os.PRIO_PROCESS, t) for t in threads(agent)} == {before}
    finally:
        for p in procs:
            p.kill()
            p.wait()
            if p.stdout is not None:
                p.stdout.close()


def test_a_process_already_gone_is_said() -> None:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    assert favour_shared({"leader": p.pid}).startswith("priorities unchanged")
