"""The in-process simulator: the chapter's claims on the default scenario (docs/model.md §8), seeds fixed."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from formation.plugin_api import all_strategies
from formation.scenario import Scenario
from testbed.sim.simulate import simulate

SEEDS = (1, 2, 3)


@pytest.fixture(scope="module")
def runs() -> dict[str, list]:  # type: ignore[type-arg]
    from pathlib import Path

    paper = Scenario.from_file(Path(__file__).resolve().parents[3] / "scenarios/paper.toml")
    return {
        s: [simulate(paper, strategy=s, seed=seed) for seed in SEEDS]
        for s in ("zero", "hold", "estimate", "blend", "drop")
    }  # type: ignore[misc]


def final(runs, strategy: str) -> np.ndarray:  # type: ignore[no-untyped-def]
    return np.array([r.formation_error[-1] for r in runs[strategy]])


def test_zero_and_hold_lose_the_formation_estimate_keeps_it(runs) -> None:  # type: ignore[no-untyped-def]
    est = final(runs, "estimate")
    assert (final(runs, "zero") >= 10 * est).all()
    assert (final(runs, "hold") >= 10 * est).all()


def test_estimate_blend_and_drop_stay_at_the_noise_floor(runs) -> None:  # type: ignore[no-untyped-def]
    for strategy in ("estimate", "blend", "drop"):
        assert (final(runs, strategy) < 0.02).all(), strategy  # σ = 0.01 m per coordinate


def test_blend_lowers_the_substitution_error_covariance_after_the_transient(runs) -> None:  # type: ignore[no-untyped-def]
    for est, blend in zip(runs["estimate"], runs["blend"], strict=True):
        e = est.substitution_errors[est.substitution_epochs >= 20]
        b = blend.substitution_errors[blend.substitution_epochs >= 20]
        assert np.trace(np.cov(b.T)) < np.trace(np.cov(e.T))


def test_estimates_are_honest(runs) -> None:  # type: ignore[no-untyped-def]
    nees = np.concatenate([r.nees_values for r in runs["estimate"]])
    assert nees.mean() == pytest.approx(2.0, rel=0.15)  # d = 2


def test_the_failed_link_is_down_from_epoch_1_and_the_tree_avoids_it(runs) -> None:  # type: ignore[no-untyped-def]
    r = runs["estimate"][0]
    assert r.delivered[0].all()
    assert not r.delivered[1:, :2].any() and r.delivered[1:, 2:].all()  # links 1->2 and 2->1
    assert r.tree[0, 0] and not r.tree[1:, 0].any()
    assert (r.rigidity_rank[1:] == 6).all() and r.rigidity_rank[0] == 7  # minimally rigid minus one


def test_no_loss_converges_to_the_shape_translated_with_the_leader(paper: Scenario) -> None:
    s = paper.with_overrides(network={}, noise={"sigma_m": 0.0}, epochs=300)
    r = simulate(s, strategy="estimate")
    x = r.positions[-1]
    np.testing.assert_allclose(x - x[0], s.offsets - s.offsets[0], atol=1e-9)


def test_same_seed_same_numbers_different_seed_different(paper: Scenario) -> None:
    a, b, c = simulate(paper, seed=5), simulate(paper, seed=5), simulate(paper, seed=6)
    np.testing.assert_array_equal(a.positions, b.positions)
    assert not np.allclose(a.positions, c.positions)


def test_simulate_command_prints_json_per_strategy(paper_path) -> None:  # type: ignore[no-untyped-def]
    proc = subprocess.run(
        [sys.executable, "-m", "testbed.cli", "simulate", str(paper_path), "--strategy", "all", "--seed", "2", "--json"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    rows = json.loads(proc.stdout)
    assert [r["strategy"] for r in rows] == list(all_strategies())  # the installed plug-ins too
    for r in rows:
        assert r["seed"] == 2 and r["scenario"] == "paper" and r["scenario_file"] == str(paper_path)
        for key in ("final_formation_error_m", "peak_formation_error_m", "final_shape_error_m",
                    "substitution_cov_trace_m2", "nees_mean"):  # fmt: skip
            assert key in r
    assert rows[0]["final_formation_error_m"] > 10 * rows[2]["final_formation_error_m"]


def test_unknown_strategy_is_named_by_every_command() -> None:
    from formation.errors import TestbedError
    from testbed.cli.arguments import parse_strategies

    assert parse_strategies(None, ["estimate"]) == ["estimate"]
    every = parse_strategies("all", ["estimate"])  # the chapter's first, then installed plug-ins
    assert every[:5] == ["zero", "hold", "estimate", "blend", "drop"]
    assert parse_strategies("zero,drop", ["estimate"]) == ["zero", "drop"]
    with pytest.raises(
        TestbedError,
        match=r"--strategy 'guess': expected one of zero, hold, estimate, blend, drop(, \w+)*, "
        r"a 'package.module:name', or all$",
    ):
        parse_strategies("zero,guess", ["estimate"])


def test_a_controller_that_varies_in_time_gets_the_epoch(
    paper_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[2] / "data" / "plugins"))
    paper = Scenario.from_file(paper_path)
    late = {**paper.control.model_dump(), "controller": "bad_plugins:LATE"}  # still until epoch 5
    steps = np.diff(simulate(paper.with_overrides(control=late, epochs=8)).positions, axis=0)
    spread = np.ptp(steps, axis=1).max(axis=1)  # (epochs,) how the agents' steps differ [m]
    assert (spread[:5] < 1e-12).all()  # the reference's motion only: a rigid translation
    assert (spread[5:] > 1e-3).all()


def test_simulate_json_with_decisions_gives_each_epochs_drops_control_links_too(
    paper_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from testbed.cli import main

    lossy = tmp_path / "lossy_control.toml"  # every control link lossy, both ways
    control = '[network]\ncontrol_default = [{ model = "bernoulli", p_loss = 0.4 }]\n\n'
    text = paper_path.read_text().replace("[[network.links]]", control + "[[network.links]]", 1)
    lossy.write_text(text)
    assert main(["simulate", str(lossy), "--json", "--epochs", "10"]) == 0
    assert "decisions" not in json.loads(capsys.readouterr().out)[0]  # compact by default
    assert main(["simulate", str(lossy), "--json", "--decisions", "--epochs", "10"]) == 0
    (summary,) = json.loads(capsys.readouterr().out)
    sim = simulate(Scenario.from_file(lossy).with_overrides(epochs=10))
    epochs = summary["decisions"]
    assert [e["epoch"] for e in epochs] == list(range(10))
    for k, e in enumerate(epochs):
        assert e["dropped"]["report"] == (np.flatnonzero(~sim.report_ok[k]) + 1).tolist()
        assert e["dropped"]["estimate"] == (np.flatnonzero(~sim.estimate_ok[k]) + 1).tolist()
        assert e["passed"]["report"] == int(sim.report_ok[k].sum())
        lost = sim.scenario.directed_links[~sim.delivered[k]].tolist()
        assert sorted(e["dropped"]["formation"]) == sorted(lost)
    assert sum(len(e["dropped"]["report"]) for e in epochs) > 5  # the control links did drop
    assert main(["simulate", str(lossy), "--decisions"]) == 1  # only with --json
