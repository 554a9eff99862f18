"""Live count of recorded messages per key: a rich table on a terminal, else a log line."""

from __future__ import annotations

import logging
import sys
import time
from types import TracebackType
from typing import Any, Protocol

log = logging.getLogger("recorder")


class _Source(Protocol):
    run_id: str
    intake: Any
    written: int
    counts: dict[str, int]


class Display:
    """Shows progress every :attr:`period_s`; ``live=None`` picks the table when stdout is a TTY."""

    def __init__(self, source: _Source, live: bool | None, log_interval_s: float) -> None:
        self.source = source
        self.live = sys.stdout.isatty() if live is None else live
        self.period_s = 0.5 if self.live else max(log_interval_s, 0.1)
        self._rich: Any = None
        self._last = (time.monotonic(), 0)

    def __enter__(self) -> Display:
        if self.live:
            from rich.live import Live  # here: rich (30 ms) loads only for a terminal's table

            self._rich = Live(self._table(), refresh_per_second=2, transient=False)
            self._rich.__enter__()
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if self._rich is not None:
            self._rich.update(self._table())
            self._rich.__exit__(kind, exc, tb)

    def _rate(self) -> float:
        now, written = time.monotonic(), self.source.written
        then, before = self._last
        self._last = (now, written)
        return (written - before) / max(now - then, 1e-9)

    def update(self) -> None:
        if self._rich is not None:
            self._rich.update(self._table())
            return
        s = self.source
        dropped = sum(s.intake.dropped.values())
        log.info(
            "%s: %d messages on %d keys (%.0f/s), backlog %d, dropped %d",
            s.run_id,
            s.written,
            len(s.counts),
            self._rate(),
            s.intake.backlog(),
            dropped,
        )

    def _table(self) -> Any:
        from rich.table import Table  # only when live (see __enter__)

        s = self.source
        dropped = s.intake.dropped
        table = Table(
            title=f"recorder {s.run_id}: {self._rate():.0f} msg/s, backlog {s.intake.backlog()}"
        )
        table.add_column("key")
        table.add_column("messages", justify="right")
        table.add_column("dropped", justify="right")
        for key, count in s.counts.items():
            table.add_row(key, str(count), str(dropped.get(key, 0)))
        return table


__all__ = ["Display"]
