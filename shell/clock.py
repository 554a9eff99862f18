"""The run's clock, asked of netem over the bus (the clock's math is :mod:`formation.realtime`)."""

from __future__ import annotations

import json
import time

from formation import keys
from formation.errors import RuntimeFailure
from formation.realtime import Clock
from shell.bus import Bus


def fetch_clock(bus: Bus, run_id: str, timeout_s: float = 10.0) -> Clock:
    """Ask netem for the run's clock (after the start token)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for reply in bus.get(keys.clock(run_id), timeout_s=1.0):
            data = json.loads(reply)
            return Clock(int(data["t0_ns"]), int(data["period_ns"]))
        time.sleep(0.01)
    raise RuntimeFailure(
        f"no answer from netem's clock ({keys.clock(run_id)}) within {timeout_s:g} s"
    )
