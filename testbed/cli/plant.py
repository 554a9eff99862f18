"""``formation ros2-plant SCENARIO``: the headless ROS 2 plant, until SIGINT or SIGTERM."""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
import time
from typing import Any

from body import exit_process, require_ros2
from formation.scenario import Scenario
from shell import add_arguments, open_session
from testbed.plant import Plant

STOP_POLL_S = 0.1  # [s] how soon a SIGTERM is acted on


def cmd_plant(args: argparse.Namespace) -> int:
    scenario = Scenario.from_file(args.scenario)
    if args.epochs is not None:
        scenario = scenario.with_overrides(epochs=args.epochs)
    require_ros2("formation ros2-plant", scenario.body.pose_type, scenario.body.kind)
    if not scenario.body.robots(scenario.n):
        print(
            f"formation ros2-plant: error: {args.scenario}: body.kind = "
            f"{scenario.body.kind!r}; no agent has a ROS 2 body (set [body] kind = 'ros2')",
            file=sys.stderr,
        )
        return 1
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    # a flag, not an Event: a handler that sets an Event deadlocks if the signal lands while
    # this thread holds the Event's lock
    stopping: list[int] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, _: stopping.append(signum))
    # rmw_zenoh: the robots speak rmw_zenoh's format on a Zenoh session of the flags
    session = open_session(args) if scenario.body.kind == "rmw_zenoh" else None
    plant = Plant(scenario, args.clock, args.rate_hz, args.seed, session=session)
    print(json.dumps({"ready": True, "robots": plant.robots.ids, "clock": args.clock}), flush=True)
    try:
        while not stopping:
            time.sleep(STOP_POLL_S)
    finally:
        counts = plant.counts
        plant.close()
        if session is not None:
            session.close()
    print(json.dumps({"counts": counts}), flush=True)
    exit_process(0)  # past rclpy's teardown (body.ros2.RosNode.close)
    return 0


def register(sub: Any) -> None:
    p = sub.add_parser(
        "ros2-plant", help="the headless ROS 2 plant: a scenario's robots, without a robot"
    )
    p.add_argument("scenario", help="scenario TOML with [body] kind = 'ros2'")
    p.add_argument(
        "--clock",
        choices=("stepped", "free"),
        default="stepped",
        help="stepped: one epoch once every command is in (lockstep runs); free: at --rate-hz",
    )
    p.add_argument("--rate-hz", type=float, help="free clock's rate [Hz]; default 1 / the period")
    p.add_argument("--seed", type=int, help="the initial positions' seed (default: the scenario's)")
    p.add_argument("--epochs", type=int, help="override the scenario's epochs")
    add_arguments(p)  # body.kind = "rmw_zenoh": the Zenoh session's --mode/--connect/--listen
    p.set_defaults(func=cmd_plant)
