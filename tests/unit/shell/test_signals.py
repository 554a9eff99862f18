"""A service's signal handler never waits for a lock the code it interrupts holds."""

from __future__ import annotations

import subprocess
import sys
import textwrap

# Each round: a fresh handler, one SIGTERM a moment later, and a main thread that holds
# the Event's lock most of the time (``wait(0)`` takes it on every call). A handler that
# calls ``stopping.set()`` itself hangs in most rounds.
CHILD = textwrap.dedent(
    """
    import os, random, signal, threading, time
    from shell.serving import stop_on_signals

    def kill_soon(delay_s):
        time.sleep(delay_s)
        os.kill(os.getpid(), signal.SIGTERM)

    for _ in range(8):
        stopping = threading.Event()
        stop_on_signals(stopping)
        killer = threading.Thread(target=kill_soon, args=(random.uniform(0, 0.002),))
        killer.start()
        while not stopping.wait(0):
            pass
        killer.join()
    print("stopped 8 times", flush=True)
    """
)


def test_a_signal_landing_while_the_event_is_locked_still_stops() -> None:
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        out, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        raise AssertionError("the handler hung: the process did not stop in 30 s") from None
    assert (proc.returncode, out) == (0, "stopped 8 times\n"), err
