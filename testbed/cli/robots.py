"""``formation robots SCENARIO``: where to place each robot before a run, and its topics."""

from __future__ import annotations

import argparse
from typing import Any

from rich.console import Console
from rich.table import Table

from formation.errors import TestbedError
from testbed.cli.arguments import load_checked
from testbed.cli.tables import print_table


def cmd_robots(args: argparse.Namespace) -> int:
    from testbed.plant.robots import Robots  # here: `formation robots --help` loads no numerics

    scenario = load_checked(args.scenario)
    body = scenario.body
    if not body.robots(scenario.n):
        raise TestbedError(f"{args.scenario}: body.kind = {body.kind!r}; no agent has a robot")
    robots = Robots.of(scenario, args.seed)  # as the plant starts them
    unicycle = robots.heading is not None
    table = Table(
        title=f"{scenario.name}: each robot's start in {body.frame_id!r} or its own frame "
        f"(scale {body.scale:g}; within {body.start_tolerance_m * body.scale:g} m)"
    )
    cols = ["robot", *("xyz"[: scenario.dimension]), "pose topic", "command topic"]
    if unicycle:
        cols[1 + scenario.dimension : 1 + scenario.dimension] = ["heading [rad]"]
    if body.transforms:  # a robot in a frame of its own starts there, in its coordinates
        cols.insert(1, "frame")
    for col in cols:
        table.add_column(col, justify="right" if len(col) == 1 or col == "robot" else "left")
    for r, i in enumerate(robots.ids):
        where = [float(c) * body.scale for c in robots.x[r]]
        heading = None if robots.heading is None else float(robots.heading[r])
        transform = body.transform_of(i)
        if transform is not None:
            where = transform.from_world(where)
            heading = None if heading is None else heading - transform.rotation_rad
        row = [str(i), *([body.frame_of(i)] if body.transforms else []), *map(repr, where)]
        if heading is not None:
            row.append(repr(heading))
        table.add_row(*row, body.pose_topic_of(i), body.command_topic_of(i))
    print_table(table, Console())
    return 0


def register(sub: Any) -> None:
    p = sub.add_parser("robots", help="where to place a scenario's robots before a run")
    p.add_argument(
        "scenario",
        help="a shipped scenario's name or a scenario TOML file, with a [body] of robots",
    )
    p.add_argument("--seed", type=int, help="the initial positions' seed (default: the scenario's)")
    p.set_defaults(func=cmd_robots)
