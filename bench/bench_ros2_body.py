"""ROS 2 bodies in realtime: pose in → command out per robot, and the CPU a body adds.

Half of each team's agents (the odd ids) have ROS 2 bodies driven by the free-running
headless plant (``formation ros2-plant --clock free``, 50 Hz), the other half simulated
bodies, in the same realtime run at 10 Hz, seed 1. Pose in → command out is from the arrival
of the pose an agent steps from (on rclpy's thread) to its ``Twist``'s publish, in ms, against
the 100 ms period. The CPU of an agent process is its own ``time.process_time()`` over its
epochs, from the run's start (from its log): the baseline is a simulated body's agent of the same run, the ratio a
robot's over it. DDS discovery stays on this host, in a ROS domain of the benchmark's own.
"""

from __future__ import annotations

import json
import os
import re
import select
import signal
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from formation.scenario import Scenario
from testbed.runtime.launcher import launch

SEED = 1
EPOCHS = 100
PERIOD_S = 0.1
ROOT = Path(__file__).resolve().parents[1]
CASES = [("5 agents", "paper.toml"), ("20 agents", "grid20.toml")]
CPU_LINE = re.compile(r"agent: cpu: ([0-9.]+) s over (\d+) epochs")
BODY_LINE = re.compile(r"agent: body: (\{.*\})")


def run_case(name: str, tmp: Path) -> dict[str, object]:
    base = Scenario.from_file(ROOT / "scenarios" / name)
    robots = [i for i in range(1, base.n + 1) if i % 2 == 1]
    scenario = base.with_overrides(
        epochs=EPOCHS,
        runtime={"mode": "realtime", "realtime_period_s": PERIOD_S},
        body={"kind": "ros2", "agents": robots},
    )
    path = tmp / f"{base.name}-ros2.toml"
    path.write_text(scenario.to_toml())
    runs = tmp / f"runs-{base.name}"
    with (tmp / "plant.log").open("a") as log:
        plant = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "testbed.cli",
                "ros2-plant",
                str(path),
                "--clock",
                "free",
                "--rate-hz",
                "50",
            ],
            stdout=subprocess.PIPE,
            stderr=log,
            text=True,
        )
    assert plant.stdout is not None
    try:
        ready, _, _ = select.select([plant.stdout], [], [], 60)
        if not ready or not json.loads(plant.stdout.readline())["ready"]:
            raise RuntimeError("the plant did not start")
        outcome = launch(scenario, seed=SEED, runs_dir=runs, record=False)
    finally:
        plant.send_signal(signal.SIGTERM)
        plant.communicate(timeout=20)
    cpu: dict[bool, list[float]] = {True: [], False: []}  # per agent-epoch [ms], robot or not
    p50: list[float] = []
    p99: list[float] = []
    for log_path in sorted(outcome.run_dir.glob("logs/agent-*.log")):
        i = int(log_path.stem.split("-")[1])
        text = log_path.read_text()
        match = CPU_LINE.search(text)
        if match:
            cpu[i in robots].append(1e3 * float(match[1]) / max(int(match[2]), 1))
        body = BODY_LINE.search(text)
        if body:
            latency = json.loads(body[1]).get("pose_to_command_ms", {})
            p50.append(latency.get("p50", float("nan")))
            p99.append(latency.get("p99", float("nan")))
    return {
        "final_error_m": float(outcome.formation_error[-1]),
        "pose_to_command_p50_ms": statistics.median(p50),
        "pose_to_command_p99_ms": max(p99),
        "cpu_ms_per_epoch_robot": statistics.median(cpu[True]),
        "cpu_ms_per_epoch_simulated": statistics.median(cpu[False]),
        "deadline_miss_rate": outcome.deadline_miss_rate(),
    }


def main() -> None:
    os.environ.setdefault("ROS_DOMAIN_ID", str(60 + os.getpid() % 40))  # DDS ports < 32768
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    print(f"seed {SEED}, {EPOCHS} epochs at {1 / PERIOD_S:g} Hz; odd ids are ROS 2 robots")
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["ROS_LOG_DIR"] = f"{tmp}/ros-log"  # rclpy's logs go with the run
        for label, name in CASES:
            r = run_case(name, Path(tmp))
            ratio = r["cpu_ms_per_epoch_robot"] / r["cpu_ms_per_epoch_simulated"]  # type: ignore[operator]
            print(
                f"{label}: pose in → command out p50 {r['pose_to_command_p50_ms']:.2f} ms, "
                f"p99 {r['pose_to_command_p99_ms']:.2f} ms (period {PERIOD_S * 1e3:g} ms); "
                f"CPU per agent-epoch: simulated body {r['cpu_ms_per_epoch_simulated']:.2f} ms "
                f"(baseline), ROS 2 body {r['cpu_ms_per_epoch_robot']:.2f} ms, ratio "
                f"{ratio:.2f}; final error {r['final_error_m']:.4f} m, deadline misses "
                f"{r['deadline_miss_rate']}",
                flush=True,
            )


if __name__ == "__main__":
    main()
