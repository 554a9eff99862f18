"""A subscriber attached from outside the run never slows it (shell/zenoh_config.py team_qos)."""

from __future__ import annotations

import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from formation import keys
from formation.scenario import Scenario
from formation.scenario import load as load_scenario
from shell import session_config
from testbed.runtime.launcher import launch
from testbed.sim.simulate import simulate

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def grid() -> Scenario:
    # 20 agents: enough traffic to fill a reader's queue (before the team rules: stuck at epoch 44)
    return load_scenario(ROOT / "scenarios" / "grid20.toml").with_overrides(epochs=200)


@pytest.mark.parametrize("reader", ["never_reads", "sleeps_a_second_per_sample"])
def test_a_slow_outside_subscriber_does_not_stall_a_lockstep_run(
    grid: Scenario, runs_dir: Path, reader: str
) -> None:
    held: list[Any] = []
    got = Counter[str]()
    done = False

    def slow(sample: zenoh.Sample) -> None:
        got["samples"] += 1
        if not done:
            time.sleep(1.0)

    def attach(run_id: str, endpoint: str) -> None:
        session = zenoh.open(session_config("client", endpoint, None))  # not of the team
        held.append(session)
        everything = keys.everything(run_id)
        held.append(
            session.declare_subscriber(everything)  # a FIFO nobody takes from
            if reader == "never_reads"
            else session.declare_subscriber(everything, slow)
        )

    try:
        outcome = launch(
            grid, runs_dir=runs_dir, record=False, on_started=attach, epoch_timeout_s=60
        )
    finally:
        done = True  # the reader may go now: its subscriber first, or closing waits on its queue
        for session, subscriber in zip(held[::2], held[1::2], strict=True):
            subscriber.undeclare()
            session.close()
    assert held, "the subscriber was attached"
    sim = simulate(grid)
    np.testing.assert_array_equal(outcome.positions, sim.positions)  # to the last bit
    assert Counter(d.link_class for d in outcome.decisions)["report"] == grid.n * grid.epochs
    if reader == "sleeps_a_second_per_sample":
        assert got["samples"] >= 1  # it is served what it takes, not cut off
