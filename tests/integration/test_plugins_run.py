"""Plug-ins through every command: the example package's strategy, controller and link model in
real processes, a sweep on the local pool and on a Dask cluster, and a plug-in that fails mid-run.

The example package is installed into the test venv by ``make test``, from its folder;
``tests/data/plugins`` (on ``PYTHONPATH`` for the processes) holds plug-ins that go wrong.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from analysis import summarise
from formation.scenario import Scenario, load_dict
from recorder import load_run, read_run
from testbed.cli import main
from testbed.runtime.launcher import launch
from testbed.sim.simulate import simulate
from testkit.dask_processes import DaskProcesses, dask_cluster
from testkit.summaries import summary_differences

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "formation-plugins-example" / "scenario.toml"
BAD = ROOT / "tests" / "data" / "plugins"


def env_with_bad_plugins() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "COLUMNS"}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(BAD), env.get("PYTHONPATH", "")) if p)
    return env


@pytest.fixture
def bad_plugins_importable() -> Iterator[None]:
    """Reading a recording validates its scenario: its plug-ins must be importable here too."""
    sys.path.insert(0, str(BAD))
    yield
    sys.path.remove(str(BAD))


@pytest.fixture
def example() -> Scenario:
    return Scenario.from_file(EXAMPLE)


@pytest.mark.parametrize("strategy", ["extrapolate", "hold"])
def test_a_lockstep_run_with_the_example_plugins_equals_simulate_bit_for_bit_summary_too(
    example: Scenario, runs_dir: Path, strategy: str
) -> None:
    outcome = launch(example, strategy=strategy, runs_dir=runs_dir)
    sim = simulate(example, strategy=strategy)
    np.testing.assert_array_equal(outcome.positions, sim.positions)
    run = load_run(outcome.run_dir / "run.mcap")  # the recording names the plug-ins it ran
    jammed = run.decisions[run.decisions.model == "jammer"]
    assert set(zip(jammed.source, jammed.target, strict=True)) == {(3, 5), (5, 3)}
    assert set(jammed.epoch) <= set(range(10, 20)) | set(range(40, 50))
    assert (run.scenario.strategy.name, run.scenario.control.controller) == (strategy, "saturated")
    assert run.scenario.strategy.params_of("extrapolate").horizon_epochs == 10
    recorded = read_run(outcome.run_dir / "run.mcap")
    np.testing.assert_array_equal(recorded.positions, sim.positions)
    assert summary_differences(summarise(recorded), summarise(sim.record())) == []


def test_sweep_with_every_strategy_lists_the_plugin_in_critical_md(tmp_path: Path) -> None:
    out = tmp_path / "sweep"
    args = ["sweep", str(EXAMPLE), "--topology", "none", "--loss", "0:0.8:0.4",
            "--strategy", "all", "--seeds", "3", "--epochs", "40", "--out", str(out), "--jobs", "2"]  # fmt: skip
    assert main(args) == 0
    critical = (out / "critical.md").read_text()
    assert "extrapolate" in critical and "blend" in critical
    assert "extrapolate" in (out / "runs.csv").read_text()


@pytest.fixture
def cluster(tmp_path: Path) -> Iterator[DaskProcesses]:
    with dask_cluster(tmp_path / "dask-logs", workers=1) as c:
        yield c


@pytest.mark.slow
def test_dask_workers_run_the_plugin_strategy_as_the_local_pool(
    cluster: DaskProcesses, tmp_path: Path
) -> None:
    common = ["sweep", str(EXAMPLE), "--topology", "none", "--loss", "0.3", "--strategy",
              "extrapolate,hold", "--seeds", "4", "--epochs", "30"]  # fmt: skip
    assert main([*common, "--out", str(tmp_path / "pool"), "--jobs", "1"]) == 0
    assert main([*common, "--out", str(tmp_path / "dask"), "--scheduler", cluster.address]) == 0
    for name in ("runs.csv", "critical.md"):
        assert (tmp_path / "pool" / name).read_bytes() == (tmp_path / "dask" / name).read_bytes()


def test_a_strategy_failing_mid_run_ends_it_keeping_the_recording_and_saying_why(
    paper_path: Path, tmp_path: Path, runs_dir: Path, bad_plugins_importable: None
) -> None:
    scenario = tmp_path / "failing.toml"
    text = paper_path.read_text().replace('name = "estimate"', 'name = "bad_plugins:FAILS_LATER"')
    scenario.write_text(text + '\n[strategy.params."bad_plugins:FAILS_LATER"]\nat_epoch = 6\n')
    proc = subprocess.run(
        [sys.executable, "-m", "testbed.cli", "run", str(scenario), "--runs-dir", str(runs_dir)],
        capture_output=True, text=True, timeout=300, env=env_with_bad_plugins(),
    )  # fmt: skip
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr, proc.stderr
    said = " ".join(proc.stderr.split())
    assert re.search(r"formation run: error: the run ended at epoch 6: agent-[12]: ", said), said
    assert (
        "loss strategy plug-in 'bad_plugins:FAILS_LATER' failed at epoch 6 (agent " in said
        and "Fill.values is not finite (NaN or inf) for a link it fills" in said
    ), said
    (run_dir,) = runs_dir.iterdir()
    assert f"what was recorded is kept in {run_dir}" in said, said
    # readable as it is (no `formation recover`): a summary section, every epoch before the failure
    with (run_dir / "run.mcap").open("rb") as f:
        reader = make_reader(f)
        assert reader.get_summary() is not None
        topics = {c.topic for _, c, _ in reader.iter_messages()}
    assert any(t.endswith("/agent/3/state") for t in topics), sorted(topics)[:10]
    run = read_run(run_dir / "run.mcap")
    assert np.isfinite(run.positions[:7]).all()  # x[0..6]: the states before the failing step
    report = (run_dir / "report.md").read_text()
    assert "## How the run ended" in report
    assert "a plug-in failed: agent/" in report and "failed at epoch 6" in report


def test_a_link_model_failing_in_netem_ends_the_run_at_its_epoch_keeping_the_recording(
    paper_path: Path, tmp_path: Path, runs_dir: Path, bad_plugins_importable: None
) -> None:
    scenario = tmp_path / "exploding.toml"
    text = paper_path.read_text().replace(
        'models = [{ model = "outage", start = 1 }]',
        'models = [{ model = "bad_plugins:Explodes", at_epoch = 12 }]',
    )
    scenario.write_text(text)
    proc = subprocess.run(
        [sys.executable, "-m", "testbed.cli", "run", str(scenario), "--runs-dir", str(runs_dir)],
        capture_output=True, text=True, timeout=300, env=env_with_bad_plugins(),
    )  # fmt: skip
    assert proc.returncode == 1, proc.stderr
    said = " ".join(proc.stderr.split())
    assert "Traceback" not in proc.stderr, proc.stderr
    assert "formation run: error: the run ended at epoch 12: " in said, said
    assert re.search(  # the layer sits on both directions: the one netem asked first names it
        r"netem: link model plug-in 'explodes' failed at epoch 12 \(link (1->2|2->1)\): "
        r"raised ValueError: the user's layer broke",
        said,
    ), said
    # as for a strategy: the epochs before the failure are recorded, and equal the simulator's
    (run_dir,) = runs_dir.iterdir()
    assert f"what was recorded is kept in {run_dir}" in said, said
    run = read_run(run_dir / "run.mcap")
    passing = tmp_path / "passing.toml"  # the layer passes every packet before it fails
    passing.write_text(text.replace('{ model = "bad_plugins:Explodes", at_epoch = 12 }', ""))
    sim = simulate(Scenario.from_file(passing).with_overrides(epochs=12))
    np.testing.assert_array_equal(run.positions[:13], sim.positions)  # x[0..12]


def test_formation_plugins_lists_ours_and_the_examples() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "testbed.cli", "plugins", "--json"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    rows = {(r["kind"], r["name"]): r for r in __import__("json").loads(proc.stdout)}
    assert rows["strategy", "extrapolate"]["package"].startswith("formation-plugins-example")
    assert rows["strategy", "extrapolate"]["parameters"] == ["horizon_epochs: int = 20 (>= 1)"]
    assert rows["strategy", "blend"]["parameters"] == ["alpha: float = 0.5 (> 0.0, <= 1.0)"]
    assert rows["controller", "saturated"]["dynamics"] == ["single", "double", "unicycle"]
    assert rows["link_model", "jammer"]["parameters"][0] == (
        "links: tuple[tuple[int, int], ...] (length >= 1)"
    )
    assert rows["link_model", "bernoulli"]["package"].startswith("formation-testbed")


def test_a_bad_plugin_is_refused_before_any_process_starts(
    paper_path: Path, tmp_path: Path, runs_dir: Path
) -> None:
    scenario = tmp_path / "bad.toml"
    scenario.write_text(
        paper_path.read_text().replace('name = "estimate"', 'name = "bad_plugins:WRONG_SHAPE"')
    )
    for command in ("run", "simulate"):
        extra = ["--runs-dir", str(runs_dir)] if command == "run" else []
        proc = subprocess.run(
            [sys.executable, "-m", "testbed.cli", command, str(scenario), *extra],
            capture_output=True, text=True, timeout=120, env=env_with_bad_plugins(),
        )  # fmt: skip
        assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
        assert (
            f"formation {command}: error: {scenario}: strategy.name = 'bad_plugins:WRONG_SHAPE'; "
            "loss strategy plug-in 'bad_plugins:WRONG_SHAPE': on a probe of 3 links: "
            "Fill.values has the shape (1, 2); expected (3, 2)"
        ) in " ".join(proc.stderr.split()), proc.stderr
    assert list(runs_dir.iterdir()) == []  # nothing started
    _ = load_dict  # the unit tests pin each case of the loader
