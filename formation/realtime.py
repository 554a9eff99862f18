"""Wall-clock epochs for realtime mode: one period, fixed phase deadlines within it.

Epoch ``k`` spans ``[t0 + kP, t0 + (k+1)P)``: agents publish ``x_i[k]`` as soon as
they have it (``x[0]`` just before ``t0``), take what arrived by ``STATE_DEADLINE·P``
and report, the leader takes the reports that arrived by ``REPORT_DEADLINE·P`` (or
estimates at once when every agent's report is in), agents take the estimate that arrived
by ``ESTIMATE_DEADLINE·P`` (or step at once when it is in) and publish ``x[k+1]``. What
arrives later is lost (and counted as a deadline miss). Deciding before a deadline
once nothing more can come gives what the deadline would, and the next phase more
time. Times are ``time.time_ns()`` so hosts share them.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass

# States go out at the previous epoch's 0.85 at the latest (at once, when the estimates
# come early), so 0.20 gives them 0.35 of a period or more, and the reports 0.40
# (bench_realtime: late reports led the misses at 0.25).
STATE_DEADLINE = 0.20
REPORT_DEADLINE = 0.60
ESTIMATE_DEADLINE = 0.85


@dataclass(frozen=True)
class Clock:
    t0_ns: int
    period_ns: int

    def at(self, epoch: int, fraction: float = 0.0) -> int:
        return self.t0_ns + int((epoch + fraction) * self.period_ns)

    def epoch_of(self, t_ns: int) -> int:
        """The epoch under way at ``t_ns`` (negative before the clock's first)."""
        return (t_ns - self.t0_ns) // self.period_ns

    def to_json(self) -> bytes:
        return json.dumps({"t0_ns": self.t0_ns, "period_ns": self.period_ns}).encode()


def sleep_until(t_ns: int) -> None:
    delay = (t_ns - time.time_ns()) / 1e9
    if delay > 0:
        time.sleep(delay)
