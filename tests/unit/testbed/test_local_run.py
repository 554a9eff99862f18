"""The launcher's run object without a run: what it does before :meth:`LocalRun.start`, and
that a failure in :meth:`~LocalRun.start` or :meth:`~LocalRun.wait` ends every child first.

A stand-in child (``python -m timeit`` sleeping) takes the services' place; no network.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from formation.errors import RunEnded, RuntimeFailure
from formation.scenario import Scenario
from testbed.runtime.launcher import LocalRun, RunHooks, make_run_id

SLEEP = "import time; time.sleep(60)"


def sleeper(run: LocalRun) -> None:
    """Start one child that would outlive the test, in place of the services."""
    run.group.start("sleeper", "timeit", "-n", "1", SLEEP)


def test_a_run_resolves_its_settings_and_touches_nothing_before_it_starts(
    paper: Scenario, tmp_path: Path
) -> None:
    run = LocalRun(paper, strategy="hold", seed=7, runs_dir=tmp_path, pool=2)
    assert run.scenario.strategy.name == "hold" and run.scenario.seed == 7
    assert run.run_id.startswith(f"{paper.name}-hold-s7-") and run.run_dir.parent == tmp_path
    assert run.startup_timeout_s == 60.0 + 0.2 * paper.n
    assert run.members[:5] == ["launcher", "router", "recorder", "netem", "leader"]
    assert [m.split("-")[0] for m in run.members[5:]] == ["pool", "pool"]
    assert run.hooks == RunHooks() and not run.run_dir.exists() and not run.group.children


def test_a_restart_policy_is_refused_with_robot_bodies_in_realtime_before_anything_starts(
    paper: Scenario, tmp_path: Path
) -> None:
    robots = paper.with_overrides(
        runtime={"mode": "realtime", "realtime_period_s": 0.2},
        body={"kind": "ros2", "agents": [2, 4]},
    )
    with pytest.raises(
        RuntimeFailure,
        match=r"^--restart on-failure with ROS 2 robot bodies in realtime \(agents 2, 4\): an "
        r"agent is lost when its robot's pose stops coming, and a new process would wait on "
        r"the same silent robot; run without --restart \(a lost robot's agent stays lost\) or "
        r"in lockstep$",
    ):
        LocalRun(robots, runs_dir=tmp_path, restart="on-failure")
    assert not list(tmp_path.iterdir())
    LocalRun(robots, runs_dir=tmp_path)  # without the policy
    lockstep = robots.with_overrides(runtime={"mode": "lockstep"})
    LocalRun(lockstep, runs_dir=tmp_path, restart="on-failure")  # netem says where to rejoin


def test_waiting_for_a_run_not_started_is_an_error_that_names_it(
    paper: Scenario, tmp_path: Path
) -> None:
    run = LocalRun(paper, runs_dir=tmp_path)
    with pytest.raises(RuntimeError, match=rf"run {run.run_id} is not started"):
        run.wait()
    run.stop()
    run.stop()  # stopping again does nothing


def test_a_start_that_fails_ends_every_child_before_it_raises(
    paper: Scenario, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    run = LocalRun(paper, runs_dir=tmp_path)

    def fail(self: LocalRun) -> None:
        sleeper(self)
        raise OSError("no router")

    monkeypatch.setattr(LocalRun, "_prepare", lambda self: None)
    monkeypatch.setattr(LocalRun, "_start_services", fail)
    with pytest.raises(OSError, match="no router"):
        run.start()
    (child,) = run.group.children
    assert child.proc.poll() is not None  # ended by PID, not left running


def test_a_plug_in_ending_the_run_while_it_is_followed_names_the_run_dir(
    paper: Scenario, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    run = LocalRun(paper, runs_dir=tmp_path)
    sleeper(run)

    def plug_in_fails(self: LocalRun) -> None:
        raise RunEnded("the strategy raised", 3, "")

    monkeypatch.setattr(LocalRun, "_follow", plug_in_fails)
    with pytest.raises(RunEnded, match="at epoch 3") as ended:
        run.wait()
    assert ended.value.run_dir == str(run.run_dir)
    assert run.group.children[0].proc.poll() is not None


def test_a_strategy_named_by_import_path_makes_a_plain_folder_name(paper: Scenario) -> None:
    run_id = make_run_id(paper.with_overrides(name="my run/1"), "my_pkg.strategies:FANCY", 3)
    assert run_id.startswith("my_run_1-my_pkg.strategies.FANCY-s3-")
    assert re.fullmatch(r"[A-Za-z0-9._+-]+", run_id), run_id
