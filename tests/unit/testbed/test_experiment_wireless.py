"""``formation experiment wireless`` on a small grid with fixed seeds: its orderings."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from formation.scenario import STRATEGIES, Scenario
from testbed.cli import main
from testbed.experiments.grid import critical
from testbed.experiments.wireless import (
    CASES,
    WirelessResult,
    WirelessSpec,
    longest_edge,
    run_wireless,
    wireless_variant,
    write_outputs,
)
from testkit.report_files import missing

ROOT = Path(__file__).resolve().parents[3]
RANGES = (0.75, 1.0, 1.5, 3.0)
SEEDS = (1, 2, 3, 4, 5, 6)


@pytest.fixture(scope="module")
def small() -> WirelessResult:
    paper = Scenario.from_file(ROOT / "scenarios" / "paper.toml")
    return run_wireless(WirelessSpec(paper, ranges=RANGES, seeds=SEEDS), log=lambda _: None)


def test_the_variant_puts_every_formation_link_on_the_logistic_model() -> None:
    paper = Scenario.from_file(ROOT / "scenarios" / "paper.toml")
    spec = WirelessSpec(paper)
    s = wireless_variant(spec, CASES[1], 1.5)
    assert longest_edge(paper) == pytest.approx(2 * np.sin(2 * np.pi / 5))  # the diagonal
    assert s.network.links == () and s.network.control_default == ()  # the outage is gone
    for a, b in s.directed_links:
        (spec_ab,) = s.formation_link_models(int(a), int(b))
        assert spec_ab.model == "logistic"
        assert spec_ab.d50_m == pytest.approx(1.5 * longest_edge(paper))  # type: ignore[union-attr]
    assert (s.control.controller, s.control.dynamics, s.control.gain) == (
        "distance", "unicycle", 0.05,
    )  # fmt: skip
    assert s.initial == paper.initial  # the default scenario's spread


def test_critical_range_is_the_least_range_from_which_every_larger_keeps() -> None:
    grid = (0.5, 1.0, 1.5, 2.0)
    assert critical(grid, np.array([1.0, 0.5, 1.0, 1.0]), easiest="high") == 1.5
    assert critical(grid, np.array([1.0, 1.0, 1.0, 1.0]), easiest="high") == 0.5
    assert critical(grid, np.array([1.0, 1.0, 1.0, 0.9]), easiest="high") is None


def test_a_long_range_keeps_every_strategy_and_a_short_one_loses_the_chapters_strategies(
    small: WirelessResult,
) -> None:
    for case in CASES:
        for s in STRATEGIES:
            frac = small.success[(case.label, s)]
            assert frac[-1] == 1.0, (case.label, s)  # ρ = 3: every link nearly always up
            assert frac[0] < frac[-1], (case.label, s)  # ρ = 0.75: the diagonals out of range


def test_zero_needs_the_longest_range_and_the_leaders_estimate_helps_out_of_range(
    small: WirelessResult,
) -> None:
    for case in CASES:
        crit = {s: small.critical[(case.label, s)] for s in STRATEGIES}
        assert all(c is not None for c in crit.values())
        assert all(crit["zero"] > c for s, c in crit.items() if s != "zero")  # type: ignore[operator]
        at = {s: small.success[(case.label, s)][0] for s in STRATEGIES}  # ρ = 0.75
        # Out of range with the leader reached, substituting its estimate keeps more seeds
        # than holding the last value or substituting zero.
        assert min(at["estimate"], at["blend"]) > max(at["hold"], at["zero"])


def test_substituting_zero_drives_the_unicycles_into_their_limits(small: WirelessResult) -> None:
    def saturated(case: str, s: str, rho: float) -> int:
        return sum(r["saturated_steps"] for r in small.rows
                   if (r["case"], r["strategy"], r["range_multiple"]) == (case, s, rho))  # fmt: skip

    uni, points = CASES[1].label, CASES[0].label
    at_short = {s: saturated(uni, s, 0.75) for s in STRATEGIES}
    assert all(at_short["zero"] > 2 * v for s, v in at_short.items() if s != "zero")
    assert len({saturated(uni, s, 3.0) for s in STRATEGIES}) == 1  # nothing lost, one run
    assert all(saturated(points, s, rho) == 0 for s in STRATEGIES for rho in RANGES)


def test_outputs(small: WirelessResult, tmp_path: Path) -> None:
    write_outputs(small, tmp_path)
    with (tmp_path / "runs.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(CASES) * len(STRATEGIES) * len(RANGES) * len(SEEDS)
    assert {float(r["range_multiple"]) for r in rows} == set(RANGES)
    critical = (tmp_path / "critical.md").read_text()
    for s in STRATEGIES:
        assert f"| {s} |" in critical
    results = (tmp_path / "results.md").read_text()
    assert "out of range, the leader reached" in results
    assert (tmp_path / "phase.png").stat().st_size > 0
    opening = results.splitlines()[2]  # the conclusion, from the critical ranges measured
    for c in small.columns:
        said = opening.split(f"In **{c}**, the formation is kept in ≥ 95% of the seeds at every ")[
            1
        ]
        said = said.split(" In **")[0]
        for s in STRATEGIES:
            crit = small.critical[(c, s)]
            where = "nowhere on the grid" if crit is None else f"from {crit:g} ×"
            group = said.split(where)[1].split(")")[0]
            assert f"`{s}`" in group, (c, s, said)
    assert missing(tmp_path / "results.md", ROOT) == []


def test_the_command_writes_the_tables(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["experiment", "wireless", "--seeds", "1", "--epochs", "30", "--no-real",
                 "--out", str(tmp_path)])  # fmt: skip
    assert code == 0
    assert "| estimate |" in capsys.readouterr().out
    for name in ("runs.csv", "critical.md", "results.md", "phase.png"):
        assert (tmp_path / name).exists(), name
    assert "Real-process runs" not in (tmp_path / "results.md").read_text()
