"""``formation sweep --vary TAG.PARAM=VALUES``: a parameter of the scenario's own link models,
a plug-in's as a built-in's, swept with the rest of the network kept."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from formation.errors import SweepError
from formation.scenario import Scenario
from testbed.cli import main
from testbed.experiments.loss_variants import with_parameter

EXAMPLE = Path(__file__).resolve().parents[3] / "examples/formation-plugins-example/scenario.toml"


def test_a_parameter_is_set_in_every_model_of_its_tag_and_nothing_else() -> None:
    example = Scenario.from_file(EXAMPLE)
    varied = with_parameter(example, "jammer.length", 25)
    (link,) = varied.network.links
    bernoulli, jammer = link.models
    assert (jammer.length, jammer.every, bernoulli) == (25, 30, example.network.links[0].models[0])
    assert varied.network.formation_default == example.network.formation_default
    with pytest.raises(
        SweepError, match=r"has no link model 'outage' \(it has: bernoulli, jammer\)"
    ):
        with_parameter(example, "outage.start", 3)


def test_sweep_varies_the_plugins_parameter_and_the_loss_grows_with_it(tmp_path: Path) -> None:
    out = tmp_path / "sweep"
    args = ["sweep", str(EXAMPLE), "--topology", "none", "--vary", "jammer.length=1,30",
            "--strategy", "hold", "--seeds", "2", "--epochs", "60", "--out", str(out),
            "--jobs", "1"]  # fmt: skip
    assert main(args) == 0
    with (out / "runs.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert {(r["model"], r["loss"]) for r in rows} == {
        ("jammer.length", "1"),
        ("jammer.length", "30"),
    }
    loss = {r["loss"]: float(r["measured_loss"]) for r in rows if r["seed"] == "1"}
    assert loss["30"] > loss["1"] + 0.05  # links 3→5, 5→3 jammed all the time, not 1 epoch in 30
    assert main([*args[:-2], "--loss", "0.1"]) == 1  # the loss grid replaces the models: not both
    args[3] = "ring8"  # a topology without a jammer: refused before any cell runs
    assert main([*args[:-2], "--out", str(tmp_path / "refused")]) == 1
    assert not (tmp_path / "refused").exists()
