"""Progress as plain lines on stderr: one per stage, readable in a pipe, a log file or CI."""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TextIO

# A stage quicker than this says nothing: a short `formation simulate` prints its table alone.
QUIET_S = 2.0


class Stages:
    """Announces each of ``total`` stages of ``command`` once it has run ``quiet_s`` seconds
    (at once when ``quiet_s`` is None), and its end with its time when it was announced."""

    def __init__(
        self, command: str, total: int, quiet_s: float | None = QUIET_S, out: TextIO | None = None
    ) -> None:
        self.command, self.total, self.quiet_s = command, total, quiet_s
        self.out = out or sys.stderr
        self.done = 0
        self._lock = threading.Lock()

    def line(self, text: str) -> None:
        """One progress line, flushed: a reader of a pipe sees it now."""
        with self._lock:
            print(f"{self.command}: {text}", file=self.out, flush=True)

    @contextmanager
    def stage(self, what: str) -> Iterator[None]:
        """A stage; its start line waits ``quiet_s`` and is never printed for a quick one."""
        index = f"[{self.done + 1}/{self.total}]"
        announced = threading.Event()

        def announce() -> None:
            announced.set()
            self.line(f"{index} {what} ...")

        timer = None
        if self.quiet_s is None:
            announce()
        else:
            timer = threading.Timer(self.quiet_s, announce)
            timer.daemon = True
            timer.start()
        started = time.perf_counter()
        try:
            yield
        finally:
            if timer is not None:
                timer.cancel()
                timer.join()
        self.done += 1
        if announced.is_set():
            self.line(f"{index} {what}: done in {time.perf_counter() - started:.1f} s")


def every(total: int, lines: int = 10) -> int:
    """The step between two progress lines, so that about ``lines`` lines cover ``total``."""
    return max(1, -(-total // lines))


__all__ = ["QUIET_S", "Stages", "every"]
