"""``formation ros2-plant SCENARIO``: the headless ROS 2 plant, until SIGINT or SIGTERM."""

from __future__ import annotations

import argparse
import json
import logging
import sys
import threading
from typing import TYPE_CHECKING, Any

from shell import add_arguments

if TYPE_CHECKING:
    from formation.scenario import Scenario


def cmd_plant(args: argparse.Namespace) -> int:
    # loaded here, not at import: `formation ros2-plant --help` loads no numerics nor Zenoh
    from body import exit_process, require_ros2
    from formation.scenario import Scenario
    from shell import Service, ZenohBus, open_session, serve, stop_on_signals

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
    if scenario.body.kind == "rmw_zenoh":
        # the robots speak rmw_zenoh's format on the service's Zenoh session; the plant joins
        # no run: its service holds the session and takes the signals, as every service's does
        def body(service: Service) -> int:
            assert isinstance(service.bus, ZenohBus)
            return run_plant(scenario, args, service.stopping, service.bus.session)

        code = serve(
            "formation ros2-plant",
            lambda: Service(ZenohBus(open_session(args)), "default", "plant", 0),
            body,
        )
    else:  # ros2: no Zenoh session to serve on; the signals as a service takes them
        stopping = threading.Event()
        stop_on_signals(stopping)
        code = run_plant(scenario, args, stopping, None)
    exit_process(code)  # past rclpy's teardown (body.ros2.RosNode.close)
    return code


def run_plant(
    scenario: Scenario, args: argparse.Namespace, stopping: threading.Event, session: Any
) -> int:
    """The plant until ``stopping``; its counts printed as it stops."""
    from testbed.plant import Plant

    plant = Plant(scenario, args.clock, args.rate_hz, args.seed, session=session)
    print(json.dumps({"ready": True, "robots": plant.robots.ids, "clock": args.clock}), flush=True)
    try:
        stopping.wait()
    finally:
        counts = plant.counts
        plant.close()
    print(json.dumps({"counts": counts}), flush=True)
    return 0


def register(sub: Any) -> None:
    p = sub.add_parser(
        "ros2-plant", help="the headless ROS 2 plant: a scenario's robots, without a robot"
    )
    p.add_argument(
        "scenario",
        help="a scenario (shipped name or TOML file) with [body] kind = 'ros2', e.g. robots",
    )
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
