"""The run's clock, asked of netem over Zenoh (the clock's math is :mod:`formation.realtime`)."""

from __future__ import annotations

import json
import time

import zenoh

from formation import keys
from formation.errors import RuntimeFailure
from formation.realtime import Clock


def fetch_clock(session: zenoh.Session, run_id: str, timeout_s: float = 10.0) -> Clock:
    """Ask netem for the run's clock (after the start token)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for reply in session.get(keys.clock(run_id), timeout=1.0):
            if reply.ok is not None:
                data = json.loads(reply.ok.payload.to_bytes())
                return Clock(int(data["t0_ns"]), int(data["period_ns"]))
        time.sleep(0.01)
    raise RuntimeFailure(
        f"no answer from netem's clock ({keys.clock(run_id)}) within {timeout_s:g} s"
    )
