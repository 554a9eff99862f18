"""A recording read back into arrays, and the report: figures and numbers that match the metrics."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from matplotlib.image import imread

from formation.errors import RecordingError
from recorder.metrics import error_statistics, formation_error, shape_error
from recorder.report import FIGURES, summarize, write_report, write_report_from
from recorder.rundata import RunData, read_run
from recorder.writer import RecordingWriter


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
    np.testing.assert_array_equal(run.extra["recorded_formation_error"], result.formation_error)
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


def test_report_compares_simulated_strategies(tmp_path: Path, sim_results: dict[str, Any]) -> None:
    runs = [RunData.from_result(r) for r in sim_results.values()]
    report = write_report_from(runs, tmp_path)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert [s["label"] for s in summary] == ["hold", "estimate"]
    for s, r in zip(summary, sim_results.values(), strict=True):
        assert s["final_formation_error_m"] == float(r.formation_error[-1])
        assert s["substitutions"] == r.substitution_errors.shape[0]
        _, _, trace = error_statistics(r.substitution_errors)
        assert s["substitution_cov_trace_m2"] == pytest.approx(trace, rel=1e-12)
    assert summary[0]["final_formation_error_m"] > 10 * summary[1]["final_formation_error_m"]
    assert "| | hold | estimate |" in report.read_text()
    non_trivial_png(tmp_path / "errors.png")


def test_summary_of_a_run_without_data(sim_results: dict[str, Any]) -> None:
    run = RunData.from_result(sim_results["hold"])
    run.formation_error = np.full_like(run.formation_error, np.nan)
    run.nees_values = np.zeros(0)
    s = summarize(run)
    assert s["final_formation_error_m"] is None and s["nees_mean"] is None


def test_report_needs_the_scenario(tmp_path: Path) -> None:
    path = tmp_path / "plain.mcap"
    rec = RecordingWriter(path)
    rec.write("x/y", b"{}", 1)
    rec.close()
    with pytest.raises(RecordingError, match=r"plain\.mcap: no scenario in the metadata"):
        read_run(path)
