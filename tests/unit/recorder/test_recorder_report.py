"""A recording read back into arrays, and the report: figures and numbers that match the metrics."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from matplotlib.image import imread

from analysis import error_statistics, formation_error, shape_error, summarise, team_shape_error
from formation.errors import RecordingError
from formation.scenario import Scenario
from recorder import read_run
from recorder.recording.writer import RecordingWriter
from recorder.reporting import plots
from recorder.reporting.report import FIGURES, write_report, write_report_from
from recorder.reporting.style import GAIN_COLOUR, LOSS_COLOUR
from testbed.sim.simulate import simulate
from testkit.report_files import missing

ROOT = Path(__file__).resolve().parents[3]


def finite_equal(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal where finite, NaN in the same places."""
    return bool(np.array_equal(a, b, equal_nan=True))


def test_read_run_gives_back_the_simulated_arrays(
    tmp_path: Path, sim_results: dict[str, Any], synth: Any
) -> None:
    result = sim_results["estimate"]
    path = tmp_path / "run.mcap"
    synth.write(path, result)
    run = read_run(path)
    assert run.positions.shape == result.positions.shape
    assert np.array_equal(run.positions, result.positions)  # JSON floats round-trip exactly
    assert finite_equal(run.estimates, result.estimates)
    assert finite_equal(run.estimate_cov, result.estimate_cov)
    for name in ("observable", "delivered", "healthy", "tree", "components", "rigidity_rank"):
        assert np.array_equal(getattr(run, name), getattr(result, name)), name
    assert run.decided.all()
    np.testing.assert_allclose(run.nees_values, result.nees_values, rtol=1e-12)
    np.testing.assert_allclose(run.estimation_errors, result.estimation_errors, rtol=1e-12)
    np.testing.assert_array_equal(run.formation_error, result.formation_error)
    np.testing.assert_array_equal(run.recorded.formation_error, result.formation_error)
    assert run.substitution_errors.shape == (0, 2)  # this synthetic recording has no substitutes
    assert run.strategy == "estimate" and run.seed == result.scenario.seed


def test_a_rotated_recording_reads_as_one(
    tmp_path: Path, sim_results: dict[str, Any], synth: Any
) -> None:
    result = sim_results["hold"]
    single, rotated = tmp_path / "one" / "run.mcap", tmp_path / "many" / "run.mcap"
    synth.write(single, result)
    synth.write(rotated, result, chunk_size=4096, split_size=40_000)
    assert (rotated.parent / "run-003.mcap").exists()
    a, b = read_run(single), read_run(rotated)
    for name in ("positions", "estimates", "delivered", "tree", "rigidity_rank", "nees_values"):
        assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True), name


def non_trivial_png(path: Path) -> None:
    assert path.stat().st_size > 10_000, path
    pixels = imread(path)
    assert pixels.shape[0] > 300 and pixels.shape[1] > 400
    assert pixels[..., :3].std() > 0.05, f"{path.name} is nearly uniform"
    assert len(np.unique(pixels[..., :3].reshape(-1, 3), axis=0)) > 50


def test_report_of_a_recording(tmp_path: Path, sim_results: dict[str, Any], synth: Any) -> None:
    result = sim_results["hold"]
    path = tmp_path / "runs" / "hold" / "run.mcap"
    path.parent.mkdir(parents=True)
    synth.write(path, result)
    report = write_report(path)
    assert report == path.parent / "report.md"
    for name in FIGURES:
        non_trivial_png(path.parent / f"{name}.png")
    (summary,) = json.loads((path.parent / "summary.json").read_text())
    s = result.scenario
    x = read_run(path).positions
    fe = formation_error(x, s.edge_array, s.weights)
    se = shape_error(x, s.edge_array, s.offsets)
    assert summary["final_formation_error_m"] == float(fe[-1])
    assert summary["peak_formation_error_m"] == float(fe.max())
    assert summary["final_shape_error_m"] == float(se[-1])
    assert summary["nees_mean"] == pytest.approx(float(result.nees_values.mean()), rel=1e-12)
    _, _, trace = error_statistics(result.estimation_errors)
    assert summary["estimation_cov_trace_m2"] == pytest.approx(trace, rel=1e-12)
    assert summary["drops"] == {"1->2": len(x) - 2, "2->1": len(x) - 2}
    assert summary["longest_outage"]["1->2"] == len(x) - 2
    assert summary["recorded_metrics_max_gap_m"] == 0.0
    assert summary["epochs_not_rigid"] == len(x) - 2  # rank 6 < 7 once 1-2 is down
    text = report.read_text()
    assert f"| final formation error [m] | {float(fe[-1]):.4g} |" in text
    for name in FIGURES:
        assert f"]({name}.png)" in text
    lost = f"loses the formation (final formation error {float(fe[-1]):.3g} m, over the 0.05 m"
    assert text.startswith("# paper: ") and lost in text.splitlines()[2]  # the conclusion
    assert f"`{path}`" in text and missing(report, ROOT) == []  # the recording, named


def test_report_compares_simulated_strategies(tmp_path: Path, sim_results: dict[str, Any]) -> None:
    runs = [r.record() for r in sim_results.values()]
    report = write_report_from(runs, tmp_path)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert [s["label"] for s in summary] == ["hold", "estimate"]
    for s, r in zip(summary, sim_results.values(), strict=True):
        assert s["final_formation_error_m"] == float(r.formation_error[-1])
        assert s["substitutions"] == r.substitution_errors.shape[0]
        _, _, trace = error_statistics(r.substitution_errors)
        assert s["substitution_cov_trace_m2"] == pytest.approx(trace, rel=1e-12)
    assert summary[0]["final_formation_error_m"] > 10 * summary[1]["final_formation_error_m"]
    assert "|  | hold | estimate |" in report.read_text()
    non_trivial_png(tmp_path / "errors.png")


def test_summary_of_a_run_without_data(sim_results: dict[str, Any]) -> None:
    run = sim_results["hold"].record()
    run.formation_error = np.full_like(run.formation_error, np.nan)
    run.nees_values = np.zeros(0)
    s = summarise(run)
    assert s["final_formation_error_m"] is None and s["nees_mean"] is None


def test_report_needs_the_scenario(tmp_path: Path) -> None:
    path = tmp_path / "plain.mcap"
    rec = RecordingWriter(path)
    rec.write("x/y", b"{}", 1)
    rec.close()
    with pytest.raises(RecordingError, match=r"plain\.mcap: no scenario in the metadata"):
        read_run(path)


def test_the_report_shows_the_team_and_marks_each_change_by_its_event(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """events.toml as a recording holds it: no state of an agent out of the team."""
    scenario = Scenario.from_file(Path(__file__).resolve().parents[3] / "scenarios" / "events.toml")
    run = simulate(scenario, "estimate").record()
    x = run.positions.copy()
    for i in range(1, scenario.n + 1):
        published = np.zeros(len(x), dtype=bool)
        for first, last in scenario.membership.incarnations(i):
            published[first : last + 1] = True
        x[~published, i - 1] = np.nan
    run.positions = x
    run.formation_error = formation_error(x, scenario.edge_array, scenario.weights)
    run.shape_error = shape_error(x, scenario.edge_array, scenario.offsets)
    figures: dict[str, Any] = {}

    def keep(fig: Any, path: Path) -> Path:  # the figure as it is saved
        figures[path.name] = fig
        return saved(fig, path)

    saved = plots._save
    monkeypatch.setattr(plots, "_save", keep)
    text = write_report_from([run], tmp_path).read_text()
    (summary,) = json.loads((tmp_path / "summary.json").read_text())
    changes = [(c["epoch"], c["agent"], c["what"]) for c in summary["team_changes"]]
    assert changes == [(15, 6, "join"), (25, 3, "crash"), (40, 3, "restart"), (60, 5, "leave")]
    team = team_shape_error(x, scenario.edge_array, scenario.offsets)
    for c in summary["team_changes"]:  # epochs from the event until the team's shape is held
        k = c["epoch"]
        assert c["transient_epochs"] == int(np.flatnonzero(team[k:] < 0.05)[0])
    assert (
        "- estimate: agent: epochs in the team — 1: 0–80; 2: 0–80; 3: 0–25, 40–80; 4: 0–80; 5: 0–60; 6: 15–80"
        in text
    )
    for k, i, verb in [
        (15, 6, "joins"),
        (25, 3, "crashes"),
        (40, 3, "restarts"),
        (60, 5, "leaves"),
    ]:
        assert (
            f"  - epoch {k}: agent {i} {verb} (scenario event); shape error under 0.05 m after "
            in text
        )
    top, bottom = figures["errors.png"].axes
    for ax in (top, bottom):  # the team's errors where some agent is out: no gap in the curves
        assert np.isfinite(ax.get_lines()[0].get_ydata()).all()
    assert [t.get_text() for t in top.texts] == ["join 6", "crash 3", "restart 3", "leave 5"]
    for ax in (top, bottom):
        marks = [ln for ln in ax.get_lines() if len(set(ln.get_xdata())) == 1]
        assert [(ln.get_xdata()[0], ln.get_color(), ln.get_linestyle()) for ln in marks] == [
            (15, GAIN_COLOUR, ":"), (25, LOSS_COLOUR, ":"), (40, GAIN_COLOUR, ":"), (60, LOSS_COLOUR, ":")
        ]  # fmt: skip
    non_trivial_png(tmp_path / "errors.png")


def test_a_large_team_s_report_names_the_worst_links_and_marks_rigidity_without_a_rank(
    tmp_path: Path,
) -> None:
    from recorder.reporting.report import LISTED_LINKS
    from testbed.sim.team_generators import rigid_team

    s = rigid_team(
        700, 2, 0.05, seed=3, epochs=6,
        network={"formation_default": [{"model": "bernoulli", "p_loss": 0.3}]},
    )  # fmt: skip
    run = simulate(s, seed=3)
    assert (run.rigidity_rank == -1).any()  # large and flexible: only "not rigid" is known
    write_report_from([run], tmp_path)
    md = (tmp_path / "report.md").read_text()
    (line,) = [ln for ln in md.splitlines() if ln.startswith("- ") and "drops on" in ln]
    every = json.loads((tmp_path / "summary.json").read_text())[0]["drops"]  # every link
    assert len(every) > LISTED_LINKS
    assert f"{sum(every.values())} drops on {len(every)} links" in line
    assert line.count("->") == LISTED_LINKS
    first = line.split("with most: ")[1].split(",")[0]  # "a->b: count (outage)"
    assert int(first.split(": ")[1].split(" ")[0]) == max(every.values())
    assert imread(tmp_path / "topology.png").shape[0] > 0
