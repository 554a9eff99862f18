"""Robots a user wrote themselves (``testkit.ros_robot``: plain rclpy, not the project's plant),
over real Fast DDS on this host, in a ROS domain of each test's own: the first pose checked,
a QoS mismatch told with both profiles, a lost pose noticed within ``pose_timeout_s`` and the
robot stopped meanwhile; and a whole ``formation run`` in realtime against them, with a stuck
robot, a robot that publishes bad poses and a robot killed mid-run."""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import select
import signal
import subprocess
import sys
import time
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from agent.body import GRAPH_CHECK_S, RobotBodies
from analysis import formation_error, shape_error, team_errors
from formation.errors import BodyLost, PoseFrameMismatch, QosMismatch, RobotNotAtStart
from formation.scenario import Scenario
from recorder import read_run
from testbed.runtime.launcher import launch
from testkit.run_watch import KillAtEpoch, wait_for_run

pytestmark = [
    pytest.mark.integration,
    # rclpy's parameter events load lark, which imports the deprecated sre_parse
    pytest.mark.filterwarnings(
        "ignore:module 'sre_(parse|constants)' is deprecated:DeprecationWarning"
    ),
]
pytest.importorskip("rclpy", reason="the ros2 extra: pip install '.[ros2]'")
READY_S = 60.0  # [s] rclpy and Fast DDS load in a few seconds
TIMEOUT_S = 1.0  # [s] body.pose_timeout_s of these tests


@pytest.fixture
def ros_domain(
    monkeypatch: pytest.MonkeyPatch, request: pytest.FixtureRequest, tmp_path: Path
) -> int:
    """A ROS domain of this test's own (below 101: see test_ros2_body.py), discovery on this
    host only, rclpy's logs in the test's folder."""
    domain = 1 + zlib.crc32(f"{request.node.nodeid}/{os.getpid()}".encode()) % 100
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
    monkeypatch.setenv("ROS_LOG_DIR", str(tmp_path / "ros-log"))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    monkeypatch.delenv("ROS_LOCALHOST_ONLY", raising=False)
    return domain


def realtime_robots(paper: Scenario, **body: Any) -> Scenario:
    return paper.with_overrides(
        epochs=30,
        runtime={"mode": "realtime", "realtime_period_s": 0.2},
        body={"kind": "ros2", "pose_timeout_s": TIMEOUT_S, "max_speed_m_s": 0.5, **body},
    )


def starts(scenario: Scenario, ids: list[int], moved: dict[int, float] | None = None) -> list[str]:
    """``--robot`` arguments: each robot where the scenario starts its agent (``moved``: that
    many metres to the right)."""
    x0 = scenario.initial_positions()
    return [
        f"--robot={i}={float(x0[i - 1, 0]) + (moved or {}).get(i, 0.0)!r},{float(x0[i - 1, 1])!r}"
        for i in ids
    ]


@contextlib.contextmanager
def robots(log: Path, *args: str) -> Iterator[subprocess.Popen[str]]:
    """``python -m testkit.ros_robot`` until its ready line; ended by PID afterwards."""
    with log.open("a") as err:
        proc = subprocess.Popen(
            [sys.executable, "-m", "testkit.ros_robot", *args],
            stdout=subprocess.PIPE,
            stderr=err,
            text=True,
        )
    assert proc.stdout is not None
    try:
        ready, _, _ = select.select([proc.stdout], [], [], READY_S)
        line = proc.stdout.readline() if ready else ""
        assert line and json.loads(line)["ready"], f"the robots did not start: {line!r}"
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()


def robot_report(proc: subprocess.Popen[str]) -> dict[str, dict[str, Any]]:
    """What the robots print as SIGTERM ends them: each one's commands."""
    proc.send_signal(signal.SIGTERM)
    out, _ = proc.communicate(timeout=20)
    return dict(json.loads(out.strip().splitlines()[-1]))


def test_the_first_pose_the_qos_and_a_lost_pose_are_told_as_they_are(
    paper: Scenario, tmp_path: Path, ros_domain: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    # robot 5 publishes in its own odometry frame, declared with its place in the world
    odom = {"agent": 5, "frame_id": "odom5", "offset_m": [1.0, -2.0], "rotation_rad": 0.7}
    scenario = realtime_robots(paper, command_frame="body", transforms=[odom])
    log = tmp_path / "robots.log"
    far = starts(scenario, [2], moved={2: 5.0})
    c, s = math.cos(0.7), math.sin(0.7)
    x5, y5 = (scenario.initial_positions()[4] - [1.0, -2.0]).tolist()  # its start, in odom5
    in_odom = f"--robot=5={c * x5 + s * y5!r},{-s * x5 + c * y5!r}"
    with (
        robots(log, *starts(scenario, [1]), "--best-effort") as offers_less,
        robots(
            log, *far, *starts(scenario, [3, 4]), in_odom, "--frame=4=odom", "--frame=5=odom5",
            "--frame=2=", "--yaw=3=0.5",
        ) as reliable,
    ):  # fmt: skip
        bodies = RobotBodies(scenario, [1, 2, 3, 4, 5], "formation_pool_1")
        try:
            # robot 1 publishes best effort, the agent asks reliable: no pose can come
            bodies.ids = [1]  # one robot at a time: each stops the agent its own way
            with pytest.raises(
                QosMismatch,
                match=r"^agent 1: the robot's publisher on /robot1/pose offers reliability "
                r"best_effort, durability volatile, the agent's subscription requests "
                r"reliability reliable, durability volatile \(reliability incompatible\): no "
                r"pose can arrive; set body\.pose_qos to what the robot publishes$",
            ):
                bodies.wait_poses(None, READY_S)
            # the same from the ROS graph, for an RMW that raises no such event
            assert bodies.link.refused_by("/robot1/pose") == (
                "reliability best_effort, durability volatile",
                "reliability reliable, durability volatile",
                "reliability",
            )
            assert bodies.link.refused_by("/robot3/pose") is None  # reliable: it matches
            with monkeypatch.context() as rmw:  # an RMW with no QoS event (rmw_zenoh_cpp's)
                rmw.setattr(RobotBodies, "_on_mismatch", lambda *_: None)
                no_event = RobotBodies(scenario, [1], "formation_agent_1")
            try:
                began = time.monotonic()
                with pytest.raises(QosMismatch, match=r"\(reliability incompatible\)"):
                    no_event.wait_poses(None, READY_S)
                assert time.monotonic() - began >= GRAPH_CHECK_S  # told by the graph
            finally:
                no_event.close()
            offers_less.kill()
            bodies.ids = [4]  # robot 4's poses are in its odometry frame: none is used
            with pytest.raises(
                PoseFrameMismatch,
                match=r"^agent 4: the poses on /robot4/pose are in frame 'odom', not "
                r"body\.frame_id = 'world': none is used; publish them in 'world', or declare "
                r"the frame they are in \(body\.frame_id, or the robot's own in "
                r"body\.transforms\)$",
            ):
                bodies.wait_poses(None, READY_S)
            assert bodies.counts["wrong_frame"] > 0 and bodies.counts["jumps"] == 0
            bodies.ids = [2, 3, 5]  # the robots a pose can come from
            placed = bodies.wait_poses(None, READY_S)
            # robot 2 stamps no frame_id: taken as body.frame_id, counted; robot 5's odom5
            # pose is where the scenario starts it in the world
            assert bodies.counts["empty_frame"] > 0 and bodies.counts["wrong_frame"] > 0
            assert placed[5] == pytest.approx(scenario.initial_positions()[4], abs=1e-12)
            assert bodies.headings()[5] == pytest.approx(0.7, abs=1e-12)
            bodies.command({5: [0.1, 0.0]})  # east in the world: its body frame turned 0.7
            (vx, vy, *_), _ = bodies.last_twist(5) or ([], 0.0)
            assert (vx, vy) == pytest.approx((0.1 * c, -0.1 * s), abs=1e-12)
            # a world-frame cmd_vel is turned back into odom5, where the robot moves by it
            world = scenario.body.model_copy(update={"command_frame": "world"})
            in_world = RobotBodies(scenario.with_overrides(body=world), [5], "formation_agent_5")
            try:
                in_world.wait_poses(None, READY_S)
                in_world.command({5: [0.0, 0.1]})  # north in the world
                (vx, vy, *_), _ = in_world.last_twist(5) or ([], 0.0)
                assert (vx, vy) == pytest.approx((0.1 * s, 0.1 * c), abs=1e-12)
            finally:
                in_world.close()
            bodies.ids = [2, 3]
            with pytest.raises(
                RobotNotAtStart,
                match=r"^agent 2: its robot's first pose on /robot2/pose is at \(4\.38\d+, "
                r"0\.58\d+\) m, 5 m from its start \(-0\.61\d+, 0\.58\d+\) m in the "
                r"scenario; body\.start_tolerance_m = 1",
            ):
                bodies.check_start(
                    {i: scenario.initial_positions()[i - 1].tolist() for i in (2, 3)}
                )
            # robot 3 moves, then its process dies: the agent's next steps wait, the robot
            # gets a zero Twist, and the loss comes pose_timeout_s after its last pose
            bodies.ids = [3]
            bodies.command({3: [0.1, 0.0]})  # east, to a robot facing 0.5 rad north of east
            (vx, vy, *_), _ = bodies.last_twist(3) or ([], 0.0)
            turned = (0.1 * math.cos(0.5), -0.1 * math.sin(0.5))  # in REP 103's body frame
            assert (vx, vy) == pytest.approx(turned, abs=1e-12)
            reliable.kill()
            reliable.wait()
            lost_after_s = _steps_until_lost(bodies, 3)
            assert bodies.counts["stops"] == 1 and bodies.last_twist(3) == ([0.0, 0.0], 0.0)
            # the bound is pose_timeout_s after the last pose (and the wake-up of a loaded
            # machine: 0.62 s late at a load of 10 on 2 cores)
            assert TIMEOUT_S <= lost_after_s <= TIMEOUT_S + 1.0, lost_after_s
            print(f"a lost pose was noticed {lost_after_s:.3f} s after the last one came")
        finally:
            bodies.close()


def _steps_until_lost(bodies: RobotBodies, robot: int) -> float:
    """Step as a realtime agent does, once a period, until the body is lost; the time from
    the robot's last pose to the loss [s]."""
    while True:
        try:
            bodies.wait_poses(None, TIMEOUT_S)
        except BodyLost:
            return time.monotonic() - bodies.pose_arrived(robot)
        time.sleep(bodies.step_s)


def test_formation_run_in_realtime_measures_stops_and_tells_the_faults_of_a_users_robots(
    paper: Scenario, runs_dir: Path, tmp_path: Path, ros_domain: int
) -> None:
    # Robot 2 ignores its commands, robot 4 publishes a NaN and a 50 m jump in every 10
    # poses, robot 3's process is killed at epoch 8; the robots stop after 0.3 s without a
    # command, as a watchdog does. The command is re-sent at every pose (50 Hz): many more
    # commands than epochs, and the watchdog never fires.
    scenario = realtime_robots(paper)
    path = tmp_path / "robots.toml"
    path.write_text(scenario.to_toml())
    log = tmp_path / "robots.log"
    watchdog = ("--watchdog-s", "0.3")
    with (
        robots(
            log, *starts(scenario, [1, 2, 4, 5]), *watchdog, "--stuck", "2", "--bad", "4"
        ) as team,
        robots(log, *starts(scenario, [3]), *watchdog) as third,
    ):
        cli = [sys.executable, "-m", "testbed.cli", "run", str(path), "--mode", "realtime"]
        run = subprocess.Popen(
            [*cli, "--runs-dir", str(runs_dir)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, "COLUMNS": "300"},
            start_new_session=True,
        )
        kill = KillAtEpoch(["robot3"], epoch=8, pids={"robot3": third.pid})
        try:
            kill.start(wait_for_run(runs_dir, run))
            out, err = run.communicate(timeout=240)
        finally:
            kill.close()
            if run.poll() is None:
                run.kill()
                run.communicate()
        report = robot_report(team)
    assert kill.killed, f"the run ended before robot 3 was killed: {err}"
    assert run.returncode == 0, err
    assert "Traceback" not in out + err
    # the agent stopped stepping once its robot's pose was stale, and left: its states end
    # within a few epochs of the kill, not pose_timeout_s (5 epochs) or more later
    loss = re.search(r"agent-3 \(pid \d+\) lost at epoch (\d+)", out)
    assert loss and int(loss[1]) <= kill.epoch + 4, out
    # the cause of the loss, in words
    assert re.search(
        r"agent-3 \(pid \d+\) lost at epoch \d+: its robot's pose stopped coming \(agent 3: "
        r"body lost: no usable pose on /robot3/pose for 1 s \(its newest pose\)\)",
        out,
    ), out
    # safe commands: the limit held, the command re-sent between steps, a zero at the end
    epochs = scenario.epochs
    for i, robot in report.items():
        assert robot["fastest_m_s"] <= 0.5 * (1 + 1e-12), (i, robot)
        assert robot["last"] == [0.0, 0.0] and robot["zeros"] >= 1, (i, robot)
    assert report["1"]["commands"] > 3 * epochs and report["1"]["watchdog_stops"] == 0
    # the bad poses were counted, in the summary
    counted = re.search(
        r"robots: \d+ poses, (\d+) rejected \((\d+) not finite, (\d+) jumps, 0 in another", out
    )
    assert counted and int(counted[2]) > 0 and int(counted[3]) > 0, out
    # measured: the stuck robot's poses, not its agent's states, are the run's positions
    (run_dir,) = runs_dir.glob("*/run.mcap")
    recorded = read_run(run_dir)
    assert recorded.computed is not None
    x0 = scenario.initial_positions()
    stuck = recorded.positions[:, 1]
    assert np.abs(stuck[np.isfinite(stuck).all(axis=1)] - x0[1]).max() < 1e-12
    (summary,) = json.loads((run_dir.parent / "summary.json").read_text())
    # the lost robot's silence is a cause of its own, not the testbed's misses: what its agent
    # never took is counted there, and the books balance
    books = json.loads((run_dir.parent / "deadlines.json").read_text())
    assert books["robot_silent"] > 0 and books["unaccounted"] == 0, books
    assert set(books["deadline_misses"]["by_cause"]) == {
        "late_sender",
        "late_netem",
        "late_leader",
        "scheduling",
    }
    assert f"{books['robot_silent']} packets late or never taken as agents waited" in out
    assert summary["team"]["3"] == [[0, int(loss[1]) - 1]]
    tracking = summary["tracking"]
    assert tracking["robots"]["2"]["final_m"] > 0.1 and "2" in tracking["warning"]
    assert re.search(r"robot 2: tracking error final \d", out)
    assert "robot 2 did not follow" in tracking["warning"] or "robots 2" in tracking["warning"]
    # the headline error is the robots' poses', not what their agents' states claim
    s = scenario

    def final_error(x: np.ndarray) -> float:
        fe, se = (
            formation_error(x, s.edge_array, s.weights),
            shape_error(x, s.edge_array, s.offsets),
        )
        team, _ = team_errors(x, recorded.present, fe, se, s.edge_array, s.weights, s.offsets)
        return float(team[-1])

    measured, claimed = final_error(recorded.positions), final_error(recorded.computed)
    assert summary["final_formation_error_m"] == measured != claimed


def test_a_robot_far_from_its_start_keeps_the_run_from_starting_with_a_clear_error(
    paper: Scenario, runs_dir: Path, tmp_path: Path, ros_domain: int
) -> None:
    scenario = realtime_robots(paper)
    path = tmp_path / "robots.toml"
    path.write_text(scenario.to_toml())
    far = starts(scenario, [1, 2, 3, 4, 5], moved={3: 1e6})
    with robots(tmp_path / "robots.log", *far):
        cli = [sys.executable, "-m", "testbed.cli", "run", str(path), "--mode", "realtime"]
        done = subprocess.run(
            [*cli, "--runs-dir", str(runs_dir)],
            capture_output=True,
            text=True,
            timeout=240,
            start_new_session=True,
        )
    assert done.returncode == 1 and "Traceback" not in done.stdout + done.stderr
    assert re.search(
        r"agent-3 \(pid \d+\) exited with code 1 before the run started .*\n.*agent 3: its "
        r"robot's first pose on /robot3/pose is at \(999999, -0\.762\d+\) m, 1e\+06 m from its "
        r"start \(-0\.892\d+, -0\.762\d+\) m in the scenario; body\.start_tolerance_m = 1",
        done.stderr,
    ), done.stderr
    assert not list(runs_dir.glob("*/report.md"))  # no epoch ran


def test_scenario_events_with_a_users_robots_in_realtime(runs_dir: Path, ros_domain: int) -> None:
    # events.toml with robots: 6 joins at 15, 3 crashes at 10 (its process killed: its robot's
    # watchdog stops it) and restarts at 40, from where its robot stands (6 s to start rclpy)
    scenario = Scenario.from_file(Path(__file__).resolve().parents[2] / "scenarios/events.toml")
    scenario = scenario.with_overrides(
        epochs=45,
        events=[
            {"epoch": 15, "agent": 6, "action": "join"},
            {"epoch": 10, "agent": 3, "action": "crash"},
            {"epoch": 40, "agent": 3, "action": "restart"},
        ],
        runtime={"mode": "realtime", "realtime_period_s": 0.2},
        body={"kind": "ros2", "pose_timeout_s": 2.0, "max_speed_m_s": 0.5},
    )
    with robots(
        runs_dir.parent / "robots.log", *starts(scenario, [*range(1, 7)]), "--watchdog-s", "0.3"
    ) as team:
        outcome = launch(scenario, strategy="hold", runs_dir=runs_dir)
        report = robot_report(team)
    s = outcome.summary()
    run = read_run(outcome.run_dir / "run.mcap")
    published = scenario.membership.published
    # each agent's states and its robot's measured poses in its parts only, epoch for epoch
    assert (run.present == published).all(), np.argwhere(run.present != published)
    assert run.computed is not None
    measured = np.isfinite(run.computed).all(axis=2)  # a pose recorded while it took part
    assert (measured == published).all(), np.argwhere(measured != published)  # (epoch, agent)
    assert run.recorded.skipped.total == 0, run.recorded.skipped.describe()
    # the restart steps from its robot's pose: where the watchdog stopped it after the kill
    assert np.linalg.norm(run.positions[40, 2] - run.positions[10, 2]) < 0.5 * 0.3 + 0.05
    assert s["unaccounted"] == 0, s["deadline"]
    for i, robot in report.items():  # every robot's last command a zero, the limit held
        assert robot["last"] == [0.0, 0.0] and robot["fastest_m_s"] <= 0.5 * (1 + 1e-12), (i, robot)
