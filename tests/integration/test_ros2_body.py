"""Agents whose bodies are ROS 2 robots, through the headless plant: real rclpy nodes over
Fast DDS, discovery kept to this host (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST), a ROS
domain of each test's own."""

from __future__ import annotations

import contextlib
import json
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

from formation.errors import RuntimeFailure
from formation.scenario import STRATEGIES, Scenario
from recorder import read_run, recover
from testbed.runtime.launcher import launch
from testbed.sim.simulate import simulate
from testkit.run_watch import KillAtEpoch
from testkit.zenoh_peer import free_port

pytestmark = pytest.mark.integration
pytest.importorskip("rclpy", reason="the ros2 extra: pip install '.[ros2]'")
READY_S = 60.0  # [s] the plant's start: rclpy and Fast DDS load in a few seconds


@pytest.fixture
def ros_domain(
    monkeypatch: pytest.MonkeyPatch, request: pytest.FixtureRequest, tmp_path: Path
) -> int:
    """A ROS domain of this test's own, and discovery on this host only, for every process;
    rclpy's logs in the test's folder."""
    # Fast DDS listens on 7400 + 250 * domain + …: domains up to 100 keep its ports below the
    # ephemeral range, where the tests' free ports (Zenoh's) come from. With domains up to 200
    # the agents twice never got the plant's first pose (a participant off its usual port is
    # not found by discovery on the local host: the likely cause)
    domain = 1 + zlib.crc32(f"{request.node.nodeid}/{os.getpid()}".encode()) % 100
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
    monkeypatch.setenv("ROS_LOG_DIR", str(tmp_path / "ros-log"))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    monkeypatch.delenv("ROS_LOCALHOST_ONLY", raising=False)
    return domain


def with_robots(scenario: Scenario, tmp_path: Path, **body: object) -> tuple[Scenario, Path]:
    robots = scenario.with_overrides(body={"kind": "ros2", **body})
    path = tmp_path / f"{scenario.name}-ros2.toml"
    path.write_text(robots.to_toml())
    return robots, path


@contextlib.contextmanager
def plant(path: Path, *args: str) -> Iterator[subprocess.Popen[str]]:
    """``formation ros2-plant`` until its ready line; ended by PID afterwards. Its log is
    beside the scenario."""
    with path.with_suffix(".plant.log").open("a") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "testbed.cli", "ros2-plant", str(path), *args],
            stdout=subprocess.PIPE,
            stderr=log,
            text=True,
            env={**os.environ, "PYTHONFAULTHANDLER": "1"},  # SIGABRT: every thread's stack
        )
    assert proc.stdout is not None
    try:
        ready, _, _ = select.select([proc.stdout], [], [], READY_S)
        line = proc.stdout.readline() if ready else ""
        assert line and json.loads(line)["ready"], f"the plant did not start: {line!r}"
        yield proc
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        proc.stdout.close()


@contextlib.contextmanager
def sim_time_node() -> Iterator[Any]:
    """A user's rclpy node started with ``use_sim_time:=true``, spinning on a thread."""
    import threading

    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node(
        "users_node", context=context, parameter_overrides=[Parameter("use_sim_time", value=True)]
    )
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.1)

    thread = threading.Thread(target=spin, daemon=True)
    thread.start()
    try:
        yield node
    finally:
        stop.set()
        thread.join(timeout=5)
        executor.shutdown(timeout_sec=1)
        node.destroy_node()
        context.try_shutdown()


def wait_for_sim_time(node: Any, ns: int, timeout_s: float = 10.0) -> int:
    """The node's clock once it reads ``ns`` (or at the timeout) [ns]."""
    deadline = time.monotonic() + timeout_s
    now = node.get_clock().now().nanoseconds
    while now != ns and time.monotonic() < deadline:
        time.sleep(0.05)  # rclpy's clock has no wait on a value
        now = node.get_clock().now().nanoseconds
    return int(now)


def plant_counts(proc: subprocess.Popen[str]) -> dict[str, int]:
    """The counts the plant prints as it stops (SIGTERM). A plant that does not stop is
    aborted, its threads' stacks in its log, and the test fails with what it printed."""
    proc.send_signal(signal.SIGTERM)
    try:
        out, _ = proc.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGABRT)
        out, _ = proc.communicate(timeout=20)
        raise AssertionError(f"the plant did not stop in 20 s; it printed {out!r}") from None
    return dict(json.loads(out.strip().splitlines()[-1])["counts"])


@pytest.mark.slow
def test_a_lockstep_run_through_the_stepped_plant_equals_the_simulator_to_the_bit(
    paper: Scenario, runs_dir: Path, tmp_path: Path, ros_domain: int
) -> None:
    scenario, path = with_robots(paper, tmp_path)
    for strategy in STRATEGIES:
        with plant(path) as proc:
            outcome = launch(scenario, strategy=strategy, runs_dir=runs_dir, record=False)  # type: ignore[arg-type]
            counts = plant_counts(proc)
        sim = simulate(scenario, strategy=strategy)  # type: ignore[arg-type]
        np.testing.assert_array_equal(outcome.positions, sim.positions, err_msg=strategy)
        assert counts == {
            "commands": scenario.n * scenario.epochs,
            "bad_commands": 0,
            "steps": scenario.epochs,
            "epoch": scenario.epochs,
        }


@pytest.mark.slow
def test_lockstep_unicycles_through_the_stepped_plant_equal_the_simulator_to_the_bit(
    paper: Scenario, runs_dir: Path, tmp_path: Path, ros_domain: int
) -> None:
    # Each robot's inner loop pose by pose: 20 twists an epoch per robot, the reference
    # agent's robot steered toward its trajectory; positions, headings and the clipped
    # sub-steps as recorded equal the simulator's.
    control = {"dynamics": "unicycle", "gain": 0.1, "unicycle": {"max_turn_rad_s": 0.5}}
    scenario, path = with_robots(paper.with_overrides(control=control, epochs=30), tmp_path)
    steps = scenario.control.unicycle.inner_steps
    clipped = 0
    for strategy in STRATEGIES:
        with plant(path) as proc:
            outcome = launch(scenario, strategy=strategy, runs_dir=runs_dir)  # type: ignore[arg-type]
            counts = plant_counts(proc)
        sim = simulate(scenario, strategy=strategy)  # type: ignore[arg-type]
        run = read_run(outcome.run_dir / "run.mcap")
        assert sim.headings is not None and sim.saturated is not None
        np.testing.assert_array_equal(outcome.positions, sim.positions, err_msg=strategy)
        np.testing.assert_array_equal(run.positions, sim.positions, err_msg=strategy)
        np.testing.assert_array_equal(run.headings, sim.headings, err_msg=strategy)
        np.testing.assert_array_equal(run.saturated, sim.saturated, err_msg=strategy)
        assert counts == {
            "commands": scenario.n * scenario.epochs * steps,
            "bad_commands": 0,
            "steps": scenario.epochs * steps,
            "epoch": scenario.epochs,
        }
        clipped += int(sim.saturated.sum())
    assert clipped > 0  # the turn limit was reached, and counted alike


@pytest.mark.slow
@pytest.mark.parametrize("dynamics", ["single", "unicycle"])
def test_robots_through_a_join_a_crash_a_restart_and_a_leave_equal_the_simulator(
    runs_dir: Path, tmp_path: Path, ros_domain: int, dynamics: str
) -> None:
    # The stepped plant waits only for the robots whose agent takes part; a robot out of the
    # team stays where it is, and a joining or restarted agent's new node gets its pose.
    events = Scenario.from_file(Path(__file__).parents[2] / "scenarios" / "events.toml")
    control = {"dynamics": dynamics, "gain": 0.1}
    scenario, path = with_robots(events.with_overrides(control=control), tmp_path)
    team = scenario.membership
    with plant(path) as proc:
        outcome = launch(scenario, strategy="estimate", runs_dir=runs_dir)
        counts = plant_counts(proc)
    sim = simulate(scenario, strategy="estimate")
    seen = np.isfinite(outcome.positions).all(axis=2)  # (E + 1, n): each agent's states
    np.testing.assert_array_equal(seen, team.published)
    np.testing.assert_array_equal(outcome.positions[seen], sim.positions[seen])
    np.testing.assert_array_equal(outcome.bodies, sim.positions)  # out of the team: where it was
    if dynamics == "unicycle":
        run = read_run(outcome.run_dir / "run.mcap")
        assert run.headings is not None and run.saturated is not None
        assert sim.headings is not None and sim.saturated is not None
        np.testing.assert_array_equal(run.headings[seen], sim.headings[seen])
        recorded = run.saturated >= 0
        np.testing.assert_array_equal(run.saturated[recorded], sim.saturated[recorded])
    steps = scenario.control.unicycle.inner_steps if dynamics == "unicycle" else 1
    moves = int(team.present[:-1].sum())  # a command per robot taking part, epoch (sub-step)
    assert counts == {
        "commands": moves * steps,
        "bad_commands": 0,
        "steps": scenario.epochs * steps,
        "epoch": scenario.epochs,
    }


@pytest.mark.filterwarnings(
    "ignore:module 'sre_(parse|constants)' is deprecated:DeprecationWarning"
)
def test_a_double_integrator_with_some_robots_equals_the_simulator_and_records_their_traffic(
    paper: Scenario, runs_dir: Path, tmp_path: Path, ros_domain: int
) -> None:
    # agents 2 and 4 are robots, each in a pool of two with a simulated body; robot 4 in a
    # frame of its own (the plant publishes it there, the agent maps it back)
    control = {**paper.control.model_dump(), "dynamics": "double", "period_s": 0.3, "gain": 0.5}
    odom = {"agent": 4, "frame_id": "odom4"}  # at the world's origin: the run stays bit for bit
    scenario, path = with_robots(
        paper.with_overrides(control=control, epochs=30), tmp_path, agents=[2, 4], transforms=[odom]
    )
    sim = simulate(scenario)
    with sim_time_node() as users, plant(path) as proc:
        outcome = launch(scenario, runs_dir=runs_dir, pool=2)
        # a node with use_sim_time follows the stepped plant's /clock: the last epoch's time
        end_ns = scenario.epochs * round(scenario.control.period_s * 1e9)
        assert wait_for_sim_time(users, end_ns) == end_ns
        counts = plant_counts(proc)
    np.testing.assert_array_equal(outcome.positions, sim.positions)
    assert counts["commands"] == 2 * scenario.epochs and counts["epoch"] == scenario.epochs
    # The robots' traffic is in the recording, in ROS 2's own encoding: read here with the
    # mcap package and rclpy's deserializer
    from geometry_msgs.msg import PoseStamped, Twist
    from mcap.reader import make_reader
    from rclpy.serialization import deserialize_message

    T = scenario.control.period_s
    seen: dict[str, list[object]] = {}
    with (outcome.run_dir / "run.mcap").open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if "/body/" in channel.topic:
                assert (schema.encoding, channel.message_encoding) == ("ros2msg", "cdr")
                assert schema.name == channel.topic.split("/", 5)[-1]
                assert b"MSG: geometry_msgs/" in schema.data  # with its dependencies
                cls = PoseStamped if "/pose/" in channel.topic else Twist
                seen.setdefault(channel.topic.split("/", 2)[-1], []).append(
                    deserialize_message(message.data, cls)
                )
    assert sorted(seen) == [
        f"body/{i}/{what}" for i in (2, 4) for what in (
            "command/geometry_msgs/msg/Twist", "pose/geometry_msgs/msg/PoseStamped")
    ]  # fmt: skip
    x = sim.positions
    for i in (2, 4):
        commands = seen[f"body/{i}/command/geometry_msgs/msg/Twist"]
        poses = seen[f"body/{i}/pose/geometry_msgs/msg/PoseStamped"]
        assert len(commands) == len(poses) == scenario.epochs
        for k, (u, pose) in enumerate(zip(commands, poses, strict=True)):
            assert [u.linear.x, u.linear.y] == ((x[k + 1, i - 1] - x[k, i - 1]) / T).tolist()  # type: ignore[attr-defined]
            p = pose.pose.position  # type: ignore[attr-defined]
            assert [p.x, p.y] == x[k + 1, i - 1].tolist()


def test_the_plant_killed_mid_run_every_agent_reports_its_body_lost_and_the_recording_is_kept(
    paper: Scenario, runs_dir: Path, tmp_path: Path, ros_domain: int
) -> None:
    scenario, path = with_robots(paper.with_overrides(epochs=100_000), tmp_path, pose_timeout_s=1.0)
    with plant(path) as proc:
        # a few epochs into the run, however loaded the machine (DDS discovery took seconds)
        kill = KillAtEpoch(["plant"], epoch=3, pids={"plant": proc.pid})
        try:
            with pytest.raises(RuntimeFailure) as err:
                launch(scenario, runs_dir=runs_dir, on_started=kill.hook(runs_dir))
        finally:
            kill.close()
    killed = kill.killed
    assert killed, "the run ended before the kill"
    names = ", ".join(f"agent-{i}: its robot's pose stopped coming" for i in range(1, 6))
    assert str(err.value) == f"every agent is gone ({names}); the run cannot go on"
    for i in range(1, 6):
        (log,) = runs_dir.glob(f"*/logs/agent-{i}.log")
        assert re.search(
            rf"agent {i}: body lost: no usable pose on /robot{i}/pose for 1 s \(waiting for "
            r"epoch \d+\)",
            log.read_text(),
        )
    (mcap,) = runs_dir.glob("*/run.mcap")
    recovered = recover(mcap)  # the recording is kept, and reads back
    run = read_run(recovered.target)
    assert run.positions.shape[0] > 2 and np.isfinite(run.positions[:2]).all()


@pytest.mark.slow
def test_a_realtime_run_through_the_free_running_plant_keeps_the_formation(
    paper: Scenario, runs_dir: Path, tmp_path: Path, ros_domain: int
) -> None:
    realtime = {"mode": "realtime", "realtime_period_s": 0.1}
    scenario, path = with_robots(paper.with_overrides(epochs=80, runtime=realtime), tmp_path)
    with plant(path, "--clock", "free", "--rate-hz", "50") as proc:
        outcome = launch(scenario, runs_dir=runs_dir, record=False)
        counts = plant_counts(proc)
    s = outcome.summary()
    assert np.isfinite(outcome.positions).all()
    # the formation is kept: the final error at the noise floor, far below where it started
    assert outcome.formation_error[-1] < 0.05 < outcome.formation_error[0]
    misses, modelled = s["deadline_misses"], s["modelled_losses"]
    books = (modelled["total"], misses["total"], s["delivered_in_time"], s["packets_sent"])
    assert books[0] + books[1] + books[2] == books[3], (books, s["deadline"])
    assert s["unaccounted"] == 0
    assert counts["commands"] >= scenario.n * (scenario.epochs - 2)
    assert counts["steps"] > 50 * 8 * 0.5  # 50 Hz over the run's 8 s, at least half of it
    print(f"realtime through the free plant: final error {outcome.formation_error[-1]:.4f} m, "
          f"misses {misses}, plant {counts}")  # fmt: skip


def test_an_rmw_zenoh_body_through_the_stepped_plant_equals_the_simulator_to_the_bit(
    paper: Scenario, runs_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # No DDS: the plant is a Zenoh router of its own that the run's router connects to (as a
    # robot's rmw_zenoh router would be), and every message is in rmw_zenoh's format.
    scenario, path = with_robots(paper.with_overrides(epochs=30), tmp_path, kind="rmw_zenoh")
    listen = f"tcp/127.0.0.1:{free_port()}"
    with plant(path, "--mode", "router", "--listen", listen) as proc:
        monkeypatch.setenv("ZENOH_CONNECT", listen)  # the run's router, to the plant
        outcome = launch(scenario, strategy="hold", runs_dir=runs_dir, record=False)
        counts = plant_counts(proc)
    np.testing.assert_array_equal(outcome.positions, simulate(scenario, strategy="hold").positions)
    assert counts["commands"] == scenario.n * scenario.epochs
    assert counts["epoch"] == scenario.epochs


def test_lockstep_unicycles_with_an_rmw_zenoh_body_equal_the_simulator_to_the_bit(
    paper: Scenario, runs_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Each robot's inner loop pose by pose in rmw_zenoh's format through the plant's own
    # router: positions, headings and clipped sub-steps as recorded equal the simulator's.
    control = {"dynamics": "unicycle", "gain": 0.1, "unicycle": {"max_turn_rad_s": 0.5}}
    scenario, path = with_robots(
        paper.with_overrides(control=control, epochs=12), tmp_path, kind="rmw_zenoh"
    )
    steps = scenario.control.unicycle.inner_steps
    listen = f"tcp/127.0.0.1:{free_port()}"
    with plant(path, "--mode", "router", "--listen", listen) as proc:
        monkeypatch.setenv("ZENOH_CONNECT", listen)  # the run's router, to the plant
        outcome = launch(scenario, strategy="hold", runs_dir=runs_dir)
        counts = plant_counts(proc)
    sim = simulate(scenario, strategy="hold")
    run = read_run(outcome.run_dir / "run.mcap")
    assert sim.headings is not None and sim.saturated is not None
    np.testing.assert_array_equal(outcome.positions, sim.positions)
    np.testing.assert_array_equal(run.positions, sim.positions)
    np.testing.assert_array_equal(run.headings, sim.headings)
    np.testing.assert_array_equal(run.saturated, sim.saturated)
    assert int(sim.saturated.sum()) > 0  # the turn limit was reached, and counted alike
    assert counts["commands"] == scenario.n * scenario.epochs * steps
    assert counts["epoch"] == scenario.epochs


@pytest.mark.slow
def test_unicycle_robots_steered_at_each_pose_keep_the_formation_in_realtime(
    paper: Scenario, runs_dir: Path, tmp_path: Path, ros_domain: int
) -> None:
    # Differential-drive robots (linear.x, angular.z) of the free plant at 50 Hz: each agent
    # steers its robot at every pose toward the epoch's look-ahead velocity.
    control = {**paper.control.model_dump(), "dynamics": "unicycle", "period_s": 0.1, "gain": 2.5}
    realtime = {"mode": "realtime", "realtime_period_s": 0.1}
    scenario, path = with_robots(
        paper.with_overrides(
            control=control, runtime=realtime, epochs=150, reference={"kind": "static"}
        ),
        tmp_path,
        pose_type="nav_msgs/msg/Odometry",
    )
    with plant(path, "--clock", "free", "--rate-hz", "50") as proc:
        outcome = launch(scenario, runs_dir=runs_dir, record=False)
        counts = plant_counts(proc)
    assert np.isfinite(outcome.positions).all()
    error = outcome.formation_error
    assert error[-1] < 0.05 < error[0], (error[0], error[-1])
    # the inner loop: many more twists than epochs
    assert counts["commands"] > 3 * scenario.n * scenario.epochs, counts
    print(f"unicycles through the free plant: formation error {error[0]:.3f} -> {error[-1]:.4f} m")
