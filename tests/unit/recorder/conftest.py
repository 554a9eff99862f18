"""Fixtures for the recorder's unit tests: simulated runs, synthetic recordings."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from formation.scenario import Scenario
from testkit.synthetic import EPOCH_NS, RUN, traffic, write_synthetic

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="session")
def synth() -> SimpleNamespace:
    """Synthetic recordings: ``synth.write(path, result)``, ``synth.traffic(result)``, ``synth.RUN``."""
    return SimpleNamespace(RUN=RUN, EPOCH_NS=EPOCH_NS, write=write_synthetic, traffic=traffic)


@pytest.fixture(scope="session")
def sim_results() -> dict[str, Any]:
    """The paper scenario simulated with two strategies (seed from the scenario file)."""
    from testbed.sim.simulate import simulate

    s = Scenario.from_file(ROOT / "scenarios" / "paper.toml")
    return {name: simulate(s, strategy=name) for name in ("hold", "estimate")}
