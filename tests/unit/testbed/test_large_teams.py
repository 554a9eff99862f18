"""The team generators and the 10,000-agent scenario shipped in ``scenarios/large/`` (issue 27)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from formation.rigidity import expected_rigidity_rank
from formation.rigidity_check import is_rigid
from formation.scenario import Scenario
from testbed.sim.team_generators import rigid_team

ROOT = Path(__file__).resolve().parents[3]
TEAM10K = ROOT / "scenarios/large/team10k.toml"


@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("redundancy", [0.0, 0.1, 0.5])
def test_rigid_team_is_rigid_with_the_spare_edges_asked(d: int, redundancy: float) -> None:
    s = rigid_team(300, d, redundancy, seed=4)
    base = expected_rigidity_rank(300, d)
    assert len(s.edges) == base + round(redundancy * base)
    assert s.dimension == d and is_rigid(s.offsets, s.edge_array)
    assert rigid_team(300, d, redundancy, seed=4).to_toml() == s.to_toml()  # seeded
    assert rigid_team(300, d, redundancy, seed=5).to_toml() != s.to_toml()


def test_rigid_team_refuses_what_it_cannot_make() -> None:
    with pytest.raises(ValueError, match="dimension = 4"):
        rigid_team(10, 4)
    with pytest.raises(ValueError, match="n = 3: at least dimension \\+ 1 = 4"):
        rigid_team(3, 3)
    with pytest.raises(ValueError, match=r"redundancy = 1\.5"):
        rigid_team(10, 2, 1.5)


def test_the_shipped_ten_thousand_is_the_generator_s() -> None:
    shipped = Scenario.from_file(TEAM10K)
    made = rigid_team(
        10_000,
        2,
        0.1,
        seed=1,
        name="team10k",
        network={"formation_default": [{"model": "bernoulli", "p_loss": 0.1}]},
        estimator={"edges": "tree", "edge_rule": "either"},
        strategy={"name": "hold"},
    )
    assert shipped.n == 10_000 and len(shipped.edges) == 21_997
    np.testing.assert_array_equal(shipped.offsets, made.offsets)
    np.testing.assert_array_equal(shipped.edge_array, made.edge_array)


def test_formation_simulate_runs_the_ten_thousand() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "testbed.cli", "simulate", str(TEAM10K), "--epochs", "4", "--json"],
        capture_output=True,
        text=True,
        timeout=300,
        check=True,
    )
    (summary,) = json.loads(out.stdout)
    assert summary["epochs"] == 4 and summary["strategy"] == "hold"
    assert np.isfinite(summary["final_formation_error_m"])
