"""``recorder.load_run``: a recording as pandas DataFrames that agree with the report's numbers."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from analysis import error_statistics
from formation import keys
from formation.codec import encode
from formation.messages import CoordinationState, Substitute
from recorder import load_run
from recorder.reporting.report import write_report
from testkit.forgeries import forgeries

ROOT = Path(__file__).resolve().parents[3]
EPOCH_NS = 1_000_000_000


@pytest.fixture
def recording(tmp_path: Path, sim_results: dict[str, Any], synth: Any) -> tuple[Path, Any]:
    """The simulated ``hold`` run with substitutes on agent 1's states and the forgeries mixed in."""
    result = sim_results["hold"]
    s = result.scenario
    inject = [
        (k, d, None, 7 * EPOCH_NS + 50 + m) for m, (k, d) in enumerate(forgeries(synth.RUN, s))
    ]
    path = tmp_path / "run" / "run.mcap"
    traffic = synth.traffic(result)
    with_subs = []
    for key, data, att, t in traffic:  # agent 3 substituted agent 1's value, off by (0.1, -0.2)
        if key == keys.agent_state(synth.RUN, 3):
            body = CoordinationState.model_validate_json(data)
            k = body.epoch
            if k >= 1:
                value = (result.positions[k - 1, 0] + [0.1, -0.2 * k]).tolist()
                body = body.model_copy(
                    update={"substituted": [Substitute(neighbour=1, value=value)]}
                )
            data = encode(body)
        with_subs.append((key, data, att, t))
    synth.write(path, result, inject=inject, messages=with_subs)
    return path, result


def test_load_run_agrees_with_the_report(recording: tuple[Path, Any]) -> None:
    path, result = recording
    write_report(path)
    (summary,) = json.loads((path.parent / "summary.json").read_text())
    run = load_run(path)
    s = run.scenario
    # drops per link
    lost = run.decisions[(run.decisions.link_class == "formation") & ~run.decisions.on_time]
    assert lost.groupby("link").size().to_dict() == summary["drops"]
    # final formation error, from the states
    assert run.metrics["formation_error_m"].iloc[-1] == summary["final_formation_error_m"]
    assert run.metrics["formation_error_m"].max() == summary["peak_formation_error_m"]
    np.testing.assert_array_equal(run.positions(), result.positions)
    # substitution covariance trace
    errors = run.substitutions[["error_x", "error_y"]].to_numpy()
    assert len(errors) == summary["substitutions"] > 0
    assert error_statistics(errors)[2] == pytest.approx(
        summary["substitution_cov_trace_m2"], rel=1e-12
    )
    # skipped, counted the same way
    assert run.skipped.as_json() == summary["skipped"]
    # columns
    assert list(run.states.columns) == ["epoch", "agent", "x", "y", "substituted"]
    assert run.states.substituted.sum() == len(run.substitutions)
    assert {"cov_xx", "cov_xy", "cov_yx", "cov_yy", "observable"} <= set(run.estimates.columns)
    est = run.estimates.set_index(["epoch", "agent"])
    k, i = 5, 3
    assert est.loc[(k, i), "x"] == result.estimates[k, i - 1, 0]
    assert est.loc[(k, i), "cov_xy"] == result.estimate_cov[k, i - 1, 0, 1]
    assert (run.metrics.recorded_formation_error_m == run.metrics.formation_error_m).all()
    assert (
        run.metrics.rigidity_rank.tolist()[: len(result.rigidity_rank)]
        == result.rigidity_rank.tolist()
    )
    assert s.name == "paper" and "scenario" in run.metadata


def test_load_run_reads_a_rotated_series(
    tmp_path: Path, sim_results: dict[str, Any], synth: Any
) -> None:
    result = sim_results["hold"]
    single, rotated = tmp_path / "one" / "run.mcap", tmp_path / "many" / "run.mcap"
    synth.write(single, result)
    synth.write(rotated, result, chunk_size=4096, split_size=40_000)
    a, b = load_run(single), load_run(rotated)
    assert len(b.files) > 2
    for name, frame in a.tables().items():
        pd.testing.assert_frame_equal(frame, b.tables()[name], check_exact=True, obj=name)


@pytest.mark.parametrize("fmt", ["parquet", "csv"])
def test_formation_export_writes_the_same_tables(
    recording: tuple[Path, Any], tmp_path: Path, fmt: str
) -> None:
    path, _ = recording
    out = tmp_path / f"out-{fmt}"
    proc = subprocess.run(
        [sys.executable, "-m", "testbed.cli", "export", str(path), str(out), "--format", fmt],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    run = load_run(path)
    for name, frame in run.tables().items():
        back = (
            pd.read_parquet(out / f"{name}.parquet")
            if fmt == "parquet"
            else pd.read_csv(out / f"{name}.csv", keep_default_na=True)
        )
        if fmt == "csv":  # text: an empty string reads back as NaN
            for col in frame.columns:
                if not pd.api.types.is_numeric_dtype(frame[col]):
                    text = back[col].astype(object)
                    back[col] = text.where(text.notna(), "").astype(frame[col].dtype)
            pd.testing.assert_frame_equal(
                back, frame, check_exact=False, rtol=1e-15, obj=name, check_dtype=False
            )
        else:
            pd.testing.assert_frame_equal(back, frame, check_exact=True, obj=name)
    meta = json.loads((out / "metadata.json").read_text())
    assert meta["skipped"]["total"] == run.skipped.total > 0


def test_the_example_reproduces_the_error_figure(
    recording: tuple[Path, Any], tmp_path: Path
) -> None:
    path, _ = recording
    png = tmp_path / "errors.png"
    proc = subprocess.run(
        [sys.executable, str(ROOT / "examples" / "error_figure.py"), str(path), str(png)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert png.stat().st_size > 10_000
