"""With robot bodies in realtime, a run's positions are the robots' recorded poses and its
agents' states stay beside them: a robot that ignores its commands is measured where it
stands, its tracking error is in the summary and the report, with a warning."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from rich.console import Console

from analysis import robot_counts_line, summarise
from body import pose_cdr
from formation import keys
from formation.codec import attachment
from formation.messages import Status
from formation.scenario import Scenario
from recorder import read_run
from recorder.reading.decoder import as_dict, decode_kind
from recorder.reporting.report import _robot_lines
from testbed.cli.robot_lines import robot_notes
from testbed.sim.simulate import simulate
from testkit.synthetic import EPOCH_NS, RUN, write_synthetic

pytest.importorskip("rosbags", reason="the ros2 extra")
STUCK = 2  # the robot that ignores its commands


def recorded_with_poses(scenario: Scenario, path: Path) -> np.ndarray:
    """A recording of ``scenario`` whose every robot follows its agent but robot ``STUCK``,
    which stays at its start; returns the poses recorded (E + 1, n, d) [m]."""
    result = simulate(scenario, "hold")
    poses = result.positions.copy()
    poses[:, STUCK - 1] = poses[0, STUCK - 1]
    kind = scenario.body.pose_type
    inject = [
        (
            keys.body(RUN, i, "pose", kind),
            pose_cdr(kind, poses[k, i - 1].tolist(), k * EPOCH_NS, "world"),
            attachment(k, k, i),  # the k-th pose of the agent's publisher: its measured x[k]
            k * EPOCH_NS + 10 + i,
        )
        for k in range(scenario.epochs + 1)
        for i in range(1, scenario.n + 1)
    ]
    end = scenario.epochs
    for i in range(1, scenario.n + 1):  # each agent's final status, with its body counts
        counts = {"packets": 8, "body_poses": 100, "body_bad_poses": i, "body_jumps": 1}
        status = Status(
            run_id=RUN, sender=f"agent/{i}", seq=9, epoch=end - 1, stamp_ns=0, role="agent",
            state="done", epochs_done=end, detail=json.dumps(counts),
        )  # fmt: skip
        key = keys.status(RUN, "agent", i)
        inject.append((key, status.model_dump_json().encode(), None, end * EPOCH_NS + 50 + i))
    write_synthetic(path, result, inject=inject)
    return poses


def test_a_realtime_run_s_positions_are_its_robots_measured_poses(
    paper: Scenario, tmp_path: Path
) -> None:
    realtime = {"mode": "realtime", "realtime_period_s": 0.2}
    scenario = paper.with_overrides(epochs=12, runtime=realtime, body={"kind": "ros2"})
    poses = recorded_with_poses(scenario, tmp_path / "run.mcap")
    run = read_run(tmp_path / "run.mcap")
    assert run.computed is not None
    np.testing.assert_array_equal(run.positions, poses)
    np.testing.assert_array_equal(run.computed, simulate(scenario, "hold").positions)
    summary = summarise(run)
    tracking = summary["tracking"]
    assert set(tracking["robots"]) == {"1", "2", "3", "4", "5"}
    assert tracking["robots"]["1"] == {"final_m": 0.0, "peak_m": 0.0, "rms_m": 0.0}
    stuck = np.linalg.norm(poses[:, STUCK - 1] - run.computed[:, STUCK - 1], axis=1)
    assert tracking["robots"]["2"]["final_m"] == stuck[-1] > 0.1
    assert tracking["warning"] == (
        "warning: robot 2 did not follow its agent: tracking error above 0.1 m "
        "(body.tracking_warning_m)"
    )
    lines = robot_notes("hold", {}, summary)
    assert lines[-1] == f"hold: {robot_counts_line(summary['robot_counts'])}"
    assert lines[1].startswith(f"hold: robot 2: tracking error final {stuck[-1]:.4g} m, peak ")
    assert lines[-2] == f"hold: {tracking['warning']}"
    assert summary["robot_counts"] == {"poses": 500, "bad_poses": 15, "jumps": 5}
    report = _robot_lines([summary])
    assert report[1] == "## Robots"
    assert report[5] == (
        f"- {run.label}: robots: 500 poses, 20 rejected (15 not finite, 5 jumps, 0 in another "
        "frame), 0 commands clipped to the speed limit, 0 re-sent between steps"
    )
    assert report[7].startswith(f"- {run.label}: robot 2: tracking error final {stuck[-1]:.4g} m")
    assert report[-1] == f"- {run.label}: **{tracking['warning']}**"


def test_in_lockstep_the_states_are_the_poses_and_nothing_is_replaced(
    paper: Scenario, tmp_path: Path
) -> None:
    scenario = paper.with_overrides(epochs=5, body={"kind": "ros2"})
    recorded_with_poses(scenario, tmp_path / "run.mcap")
    run = read_run(tmp_path / "run.mcap")
    assert run.computed is None and "tracking" not in summarise(run)
    np.testing.assert_array_equal(run.positions, simulate(scenario, "hold").positions)


def test_the_summary_counts_the_robots_poses_and_commands() -> None:
    deadline = {"packets": 9, "body_poses": 500, "body_bad_poses": 3, "body_jumps": 2}
    out = io.StringIO()
    for line in robot_notes("hold", {"deadline": deadline | {"body_clipped": 4}}, None):
        Console(file=out, width=300).print(line)
    assert out.getvalue() == (
        "hold: robots: 500 poses, 5 rejected (3 not finite, 2 jumps, 0 in another frame), 4 "
        "commands clipped to the speed limit, 0 re-sent between steps\n"
    )


def test_the_live_view_draws_each_robots_measured_pose_and_logs_its_tracking_error(
    paper: Scenario, tmp_path: Path
) -> None:
    realtime = {"mode": "realtime", "realtime_period_s": 0.2}
    scenario = paper.with_overrides(epochs=12, runtime=realtime, body={"kind": "ros2"})
    poses = recorded_with_poses(scenario, tmp_path / "run.mcap")
    computed = simulate(scenario, "hold").positions
    robots: dict[tuple[int, int], list[float]] = {}  # (robot, epoch) → the drawn sphere
    logs: dict[tuple[int, int], tuple[int, str]] = {}  # (robot, epoch) → level, line
    with (tmp_path / "run.mcap").open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages():
            if channel.topic == keys.scene(RUN):
                for e in as_dict(decode_kind("scene", message.data))["entities"]:
                    if e["id"].startswith("robot "):
                        epoch = next(int(m["value"]) for m in e["metadata"] if m["key"] == "epoch")
                        p = e["spheres"][0]["pose"]["position"]
                        robots[int(e["id"].split()[1]), epoch] = [p["x"], p["y"]]
            elif channel.topic == keys.log(RUN):
                line = as_dict(decode_kind("log", message.data))
                if line["name"].startswith("robot/"):
                    epoch = int(line["message"].split(":")[0].removeprefix("epoch "))
                    logs[int(line["name"].split("/")[1]), epoch] = (line["level"], line["message"])
    n, epochs = scenario.n, scenario.epochs
    assert set(robots) == set(logs) == {(i, k) for i in range(1, n + 1) for k in range(epochs + 1)}
    for (i, k), drawn in robots.items():
        np.testing.assert_allclose(drawn, poses[k, i - 1], rtol=0, atol=1e-12)
    level, line = logs[STUCK, epochs]
    error = float(np.linalg.norm(poses[epochs, STUCK - 1] - computed[epochs, STUCK - 1]))
    assert f"robot {STUCK} measured at" in line and f"tracking error {error:.4g} m" in line
    assert level == "WARNING" and error > 0.1
    assert logs[1, epochs][0] == "INFO" and "tracking error 0 m" in logs[1, epochs][1]
