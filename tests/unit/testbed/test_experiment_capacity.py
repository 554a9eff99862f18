"""``formation experiment capacity`` on the simulator: the load, the sweep and its files."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from formation.scenario import Scenario
from testbed.experiments.capacity import (
    CapacitySpec,
    capacity_variant,
    epoch_load,
    run_capacity,
    write_outputs,
)


def test_the_load_is_the_nominal_bytes_of_one_epoch(paper: Scenario) -> None:
    load = epoch_load(paper)
    assert load["states"] == pytest.approx(4200.0)  # 14 links × (258 + 42) B at 50 epochs
    # the states are the access point's heaviest phase: 0.20 of a 1 s period
    assert load["c_ap"] == pytest.approx(8 * load["states"] / 0.2)
    assert load["c_radio"] < load["c_ap"]


def test_a_variant_puts_the_access_point_or_every_radio_at_the_multiple(paper: Scenario) -> None:
    ap = capacity_variant(paper, "access point", 0.5, 10).network.capacity
    assert [(c.scope, c.links) for c in ap] == [("medium", "all")]
    assert ap[0].rate_bps == pytest.approx(0.5 * epoch_load(paper)["c_ap"])
    states = capacity_variant(paper, "access point (states only)", 0.5, 10).network.capacity
    assert [(c.scope, c.links, c.rate_bps) for c in states] == [
        ("medium", "formation", ap[0].rate_bps)
    ]
    radios = capacity_variant(paper, "radios", 2.0, 10).network.capacity
    assert [c.agent for c in radios] == list(range(0, paper.n + 1))


def test_the_sweep_finds_a_critical_capacity_and_writes_its_files(
    paper: Scenario, tmp_path: Path
) -> None:
    spec = CapacitySpec(
        (("paper", paper),),
        multiples=(0.25, 1.0, 2.0),
        seeds=(1, 2),
        strategies=("hold", "estimate"),
        studies=("access point",),
        epochs=30,
    )
    result = run_capacity(spec, log=lambda _: None)
    label = "access point, paper"
    assert result.success[(label, "estimate")].tolist() == [0.0, 1.0, 1.0]
    assert result.critical[(label, "estimate")] == 1.0
    assert result.critical[(label, "hold")] is None  # the chapter's link 1-2 is down
    write_outputs(result, tmp_path)
    with (tmp_path / "runs.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 3 * 2 * 2
    assert {r["strategy"] for r in rows} == {"hold", "estimate"}
    assert "| estimate | 1 × |" in (tmp_path / "critical.md").read_text()
    assert (tmp_path / "phase.png").stat().st_size > 0
    assert "## What the numbers show" in (tmp_path / "results.md").read_text()


def test_the_estimation_traffic_is_priced_by_the_states_only_access_point(
    paper: Scenario, tmp_path: Path
) -> None:
    """At a quarter of c_ap the reports and estimates on the medium cost ``estimate`` the formation
    (they queue behind the states and miss their deadlines); off it, it keeps the formation."""
    spec = CapacitySpec(
        (("paper", paper),),
        multiples=(0.25, 1.0),
        seeds=(1, 2),
        strategies=("hold", "estimate"),
        studies=("access point", "access point (states only)"),
        epochs=30,
    )
    result = run_capacity(spec, log=lambda _: None)
    assert result.success[("access point, paper", "estimate")].tolist() == [0.0, 1.0]
    assert result.success[("access point (states only), paper", "estimate")].tolist() == [1.0, 1.0]
    write_outputs(result, tmp_path)
    text = (tmp_path / "results.md").read_text()
    assert (
        "paper, critical capacity with → without: hold never → never; estimate ρ = 1 → ρ = 0.25."
        in text
    )
