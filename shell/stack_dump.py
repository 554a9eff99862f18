"""Every service dumps its threads' Python stacks to stderr (its log) on ``SIGUSR1``.

A stalled run is a question of where each process waits; the launcher asks before it
stops them (:meth:`testbed.runtime.processes.ProcessGroup.dump_stacks`).
"""

from __future__ import annotations

import faulthandler
import signal
import sys

DUMP_SIGNAL = signal.SIGUSR1


def dump_stacks_on_signal() -> None:
    """Install the handler (C-level: it works while a thread holds the GIL in native code)."""
    faulthandler.register(DUMP_SIGNAL, file=sys.stderr, all_threads=True)
