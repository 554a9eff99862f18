"""Experiments: the chapter's orderings, the sweep's critical loss rates, reproducible tables."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from formation.errors import SweepError
from formation.linkmodels import GilbertElliott
from formation.scenario import Scenario
from netem.links.models import expected_loss_rate
from testbed.cli import main
from testbed.experiments import studies
from testbed.experiments.grid import critical
from testbed.experiments.loss_variants import gilbert_elliott_at, with_loss
from testbed.experiments.paper import PaperResults, judge, run_variants
from testbed.experiments.paper_run import check_recording, run_paper
from testbed.experiments.sweep import (
    SweepSpec,
    loss_grid,
    plan_chunks,
    read_rows,
    run_chunk,
    run_sweep,
)
from testbed.sim.simulate import simulate
from testkit.forgeries import forgeries
from testkit.report_files import missing
from testkit.synthetic import EPOCH_NS, RUN, write_synthetic

ROOT = Path(__file__).resolve().parents[3]

SEEDS = (1, 2, 3, 4, 5, 6)
TABLES = ("runs.csv", "critical.md", "success.md")


def small_spec(paper: Scenario, seeds: tuple[int, ...] = SEEDS, **kw: object) -> SweepSpec:
    args: dict[str, object] = dict(
        topologies=(("paper", paper),),
        losses=(0.0, 0.25, 0.5, 0.75),
        strategies=("zero", "hold", "estimate"),
        seeds=seeds,
        epochs=200,
        seeds_per_chunk=3,
    )
    args.update(kw)
    return SweepSpec(**args)  # type: ignore[arg-type]


def test_the_chapters_orderings_on_the_default_scenario(paper: Scenario) -> None:
    runs = run_variants(paper, SEEDS[:4])
    fail = {s: float(np.mean(r.formation_error[-1])) for s, r in runs["failure"].items()}
    assert fail["zero"] > fail["hold"] > 10 * fail["estimate"]
    assert fail["estimate"] == pytest.approx(fail["blend"], rel=1e-12)  # agent 2's x̂_1 is exact
    assert fail["estimate"] < 0.01 and fail["drop"] < 0.01
    verdicts = {c.text: c.verdict for c in judge(PaperResults(paper, SEEDS[:4], runs))}
    assert verdicts["`zero` loses the formation when link 1–2 fails"] == "held"
    assert verdicts["`hold` loses the formation when link 1–2 fails"] == "held"
    assert sum(v == "held" for t, v in verdicts.items() if t.startswith("`estimate` keeps")) == 3
    blend = next(v for t, v in verdicts.items() if t.startswith("`blend`"))
    assert blend == "held in steady state only"  # lags the transient in the chapter's 50 epochs


def test_critical_loss_rate_of_estimate_beats_hold_and_zero(
    paper: Scenario, tmp_path: Path
) -> None:
    summary = run_sweep(small_spec(paper), tmp_path, jobs=1)
    crit = {s: summary.critical[("paper", "bernoulli", s)] for s in ("zero", "hold", "estimate")}
    assert crit["estimate"] is not None and crit["hold"] is not None and crit["zero"] is not None
    assert crit["estimate"] > crit["hold"] > crit["zero"]
    assert "| paper | bernoulli | 0 | 0.5 | 0.75 |" in (tmp_path / "critical.md").read_text()
    measured = summary.measured_loss[("paper", "bernoulli")]
    np.testing.assert_allclose(measured, [0.0, 0.25, 0.5, 0.75], atol=0.02)


def test_a_rerun_gives_byte_identical_tables_and_resumes(paper: Scenario, tmp_path: Path) -> None:
    spec = small_spec(paper, strategies=("hold", "estimate"), losses=(0.0, 0.5))
    run_sweep(spec, tmp_path / "a", jobs=1)
    run_sweep(spec, tmp_path / "b", jobs=2)
    for name in TABLES:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    # interrupted: only some seeds ran, a row cut short, then Ctrl-C after one more chunk
    part = tmp_path / "c"
    run_sweep(
        small_spec(paper, seeds=SEEDS[:2], strategies=("hold", "estimate"), losses=(0.0, 0.5)),
        part,
        jobs=1,
    )
    with (part / "runs.csv").open("a") as f:
        f.write("paper,bernoulli,0.5,hold,3,")

    def interrupt(done: int, total: int) -> None:
        if done > 8:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_sweep(spec, part, jobs=1, progress=interrupt)
    assert len(read_rows(part / "runs.csv")) == 20  # 8 before, the 12 of seeds 4–6 (heaviest first)
    done: list[tuple[int, int]] = []
    run_sweep(spec, part, jobs=1, progress=lambda d, t: done.append((d, t)))
    assert done[0] == (20, 24) and done[-1] == (24, 24)
    for name in TABLES:
        assert (part / name).read_bytes() == (tmp_path / "a" / name).read_bytes(), name
    calls: list[tuple[int, int]] = []
    run_sweep(spec, part, jobs=1, progress=lambda d, t: calls.append((d, t)))
    assert calls == [(24, 24)]  # nothing left to run
    assert len(read_rows(part / "runs.csv")) == 24


def test_gilbert_elliott_has_the_bernoulli_mean_rate() -> None:
    for rate in (0.0, 0.05, 0.3, 0.8, 0.95, 1.0):
        params = gilbert_elliott_at(rate, 4.0)
        spec = GilbertElliott(p=params["p"], r=params["r"], one_minus_h=1.0, one_minus_k=0.0)
        assert expected_loss_rate(spec) == pytest.approx(rate, abs=1e-9)


def test_loss_grid_and_its_errors() -> None:
    assert loss_grid("0:1:0.05") == tuple(round(0.05 * i, 10) for i in range(21))
    assert loss_grid("0.3,0.1") == (0.1, 0.3)
    with pytest.raises(SweepError, match=r"rates must be in \[0, 1\], got \[1.5, 2.0\]"):
        loss_grid("0:2:0.5")
    with pytest.raises(SweepError, match="step = 0; expected > 0"):
        loss_grid("0:1:0")
    with pytest.raises(SweepError, match="expected START:STOP:STEP"):
        loss_grid("a:b")
    rate = [0.0, 0.1, 0.2, 0.3]
    assert critical(rate, np.array([1.0, 0.95, 0.9, 1.0]), easiest="low") == 0.1
    assert critical([0.0, 0.1], np.array([0.5, 1.0]), easiest="low") is None


def test_a_foreign_csv_is_refused(paper: Scenario, tmp_path: Path) -> None:
    (tmp_path / "runs.csv").write_text("a,b\n1,2\n")
    with pytest.raises(SweepError, match=r"runs.csv: columns \['a', 'b'\]; expected"):
        run_sweep(small_spec(paper), tmp_path, jobs=1)


def test_paper_experiment_is_reproducible(paper: Scenario, tmp_path: Path) -> None:
    first = run_paper(paper, tmp_path / "a", seeds=SEEDS[:3], real=False)
    run_paper(paper, tmp_path / "b", seeds=SEEDS[:3], real=False, figures=False)
    for name in ("results.md", "seeds.csv"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    text = (tmp_path / "a" / "results.md").read_text()
    assert "## §7.2: rigidity or connectivity" in text and "| **best α** |" in text
    lines = text.splitlines()  # the conclusion first, computed from the seeds, then its figure
    assert lines[0] == "# paper: the chapter's experiment over 3 seeds"
    kept = lines[2].split(" keep the formation in all 3 seeds")[0]
    assert sorted(kept.replace(" and", ",").split(", ")) == ["`blend`", "`drop`", "`estimate`"]
    assert "`estimate` and `blend` move identically, to the bit, in every seed" in lines[2]
    assert lines[4] == "![Formation error when link 1–2 fails](formation_error_failure.png)"
    two = text.split("## Two lossy links")[1].split("\n\n")[1]  # there agent 5 fills in agent 3
    assert two.startswith("`") and "move identically" not in two
    assert "per seed [m]:" not in text and "testbed/batch.py" not in text
    assert missing(tmp_path / "a" / "results.md", ROOT) == []
    for png in (
        "positions.png",
        "substitution_covariance.png",
        "formation_error_two_lossy.png",
        "dynamic.png",
    ):
        assert (tmp_path / "a" / png).stat().st_size > 10_000
    assert first.studies["controller"].holds()
    rows = {r.label: r for r in first.studies["estimator"].rows}
    for r in rows.values():  # every healthy edge: lower covariance than the tree alone
        assert r.predicted["healthy"] < r.predicted["tree"]


def test_dynamic_formation_adapts(paper: Scenario) -> None:
    d = studies.dynamic_study(paper, SEEDS[:3], strategies=("estimate", "hold"))
    (_, leave), (_, join) = d.leave, d.join
    assert d.tree_edges[leave - 1] == 4 and d.tree_edges[leave] == 3 and d.tree_edges[join] == 4
    est = np.median(d.shape_error["estimate"], axis=1)
    assert est[join] > 0.1 > 0.02 > est[-1]  # the joiner's transient, then back to the floor
    assert d.settle("estimate", join) < 25 and d.settle("hold", join) == float("inf")


def test_cli_sweep_and_experiment(
    tmp_path: Path, paper_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "sweep"
    code = main(
        [
            "sweep",
            str(paper_path),
            "--topology",
            "octahedron3d",
            "--loss",
            "0,0.5",
            "--strategy",
            "estimate,drop",
            "--seeds",
            "2",
            "--burst",
            "--jobs",
            "2",
            "--out",
            str(out),
        ]
    )
    assert code == 0
    rows = read_rows(out / "runs.csv")
    assert len(rows) == 2 * 2 * 2 * 2 * 2
    assert {r["topology"] for r in rows} == {"paper", "octahedron3d"}
    assert {r["model"] for r in rows} == {"bernoulli", "gilbert_elliott"}
    assert (out / "phase.png").stat().st_size > 10_000
    assert main(["sweep", "--strategy", "bogus", "--out", str(out)]) == 1
    assert "--strategy 'bogus'" in capsys.readouterr().err


def test_an_event_scenario_is_judged_on_the_team_taking_part(tmp_path: Path) -> None:
    """events.toml: agent 5 leaves at 60 of 80 and stands still; the team goes on in shape."""
    events = Scenario.from_file(Path(__file__).resolve().parents[3] / "scenarios" / "events.toml")
    spec = SweepSpec(topologies=(("events", events),), losses=(0.0,), strategies=("estimate",),
                     seeds=(1, 2), epochs=events.epochs, seeds_per_chunk=2)  # fmt: skip
    run_sweep(spec, tmp_path, jobs=1)
    rows = read_rows(tmp_path / "runs.csv")
    assert [float(r["final_shape_error_m"]) < 0.05 for r in rows] == [True, True]
    assert "| events | bernoulli | 0 |" in (tmp_path / "critical.md").read_text()  # kept at 0


def test_a_real_runs_recording_is_read_back_with_what_was_skipped(
    paper: Scenario, tmp_path: Path
) -> None:
    """A real run's row states the messages its recording's reader did not trust."""
    result = simulate(paper.with_overrides(epochs=10), "hold")
    bad = forgeries(RUN, result.scenario, epoch=7)
    inject = [(key, data, None, 7 * EPOCH_NS + 50 + m) for m, (key, data) in enumerate(bad)]
    path = tmp_path / "run.mcap"
    write_synthetic(path, result, inject=inject)
    row: dict[str, object] = {}
    where, cell = check_recording(row, path, result.positions)
    assert where == str(path) and row["recorded_diff"] == 0.0, row
    assert row["skipped"] == len(bad) and cell.startswith(f"{len(bad)} (invalid ")
    clean = tmp_path / "clean.mcap"
    write_synthetic(clean, result)
    assert check_recording({}, clean, result.positions)[1] == "0"


def test_the_sweep_takes_its_final_errors_as_the_run_summary_does() -> None:
    """A cell of a scenario with events has the final errors ``formation simulate`` prints."""
    events = Scenario.from_file(Path(__file__).resolve().parents[3] / "scenarios" / "events.toml")
    spec = SweepSpec(topologies=(("events", events),), losses=(0.25,), strategies=("hold",),
                     seeds=(3,), epochs=events.epochs, seeds_per_chunk=1)  # fmt: skip
    (row,) = run_chunk(plan_chunks(spec, set())[0])
    summary = simulate(with_loss(events, "bernoulli", 0.25), "hold", seed=3).summary()
    for column in ("final_shape_error_m", "final_formation_error_m"):
        assert row[column] == format(summary[column], ".9g"), column
