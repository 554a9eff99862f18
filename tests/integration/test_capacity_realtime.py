"""Realtime with a constrained access point: netem holds each packet in its queue until it
leaves, so the queueing shows in the deadline accounting, and the books still balance."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from formation.scenario import Scenario
from testbed.runtime.launcher import launch

pytestmark = pytest.mark.integration


@pytest.mark.slow
def test_a_constrained_access_point_shows_in_the_deadline_accounting(
    paper: Scenario, runs_dir: Path
) -> None:
    network = paper.network.model_dump(by_alias=True)
    # 5 reports of ~330 B within 0.4 × 0.2 s need 165 kbit/s: at 60 kbit/s most are late
    network["capacity"] = [
        {"scope": "medium", "medium": "ap", "links": "control", "rate_bps": 60_000.0,
         "limit_packets": 8, "overhead_bytes": 42},
    ]  # fmt: skip
    scenario = paper.with_overrides(
        network=network,
        epochs=40,
        runtime={"mode": "realtime", "realtime_period_s": 0.2},
    )
    outcome = launch(scenario, runs_dir=runs_dir, record=False)
    s = outcome.summary()
    assert np.isfinite(outcome.positions).all()
    modelled, misses = s["modelled_losses"], s["deadline_misses"]
    assert modelled["queued_past_deadline"] > 0, s["deadline"]  # the queue made them late
    assert modelled["delayed_past_deadline"] >= modelled["queued_past_deadline"]
    books = (modelled["total"], misses["total"], s["delivered_in_time"], s["packets_sent"])
    assert books[0] + books[1] + books[2] == books[3], (books, s["deadline"])
    assert s["unaccounted"] == 0
    control = [d for d in outcome.decisions if d.link_class != "formation"]
    assert any(d.model == "queue_late" for d in control)  # recorded as held past its deadline
