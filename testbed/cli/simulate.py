"""``formation simulate``: the model in one process, no Zenoh."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from testbed.cli.arguments import add_common, load_checked, scenario_strategies
from testbed.cli.progress import Stages


def cmd_simulate(args: argparse.Namespace) -> int:
    from testbed.cli.tables import print_summaries
    from testbed.sim.simulate import simulate

    scenario = load_checked(args.scenario)
    if args.epochs is not None:
        scenario = scenario.with_overrides(epochs=args.epochs)
    seed = scenario.seed if args.seed is None else args.seed
    strategies = scenario_strategies(args.strategy, scenario)
    stages = Stages("formation simulate", len(strategies))
    summaries = []
    for s in strategies:
        with stages.stage(f"{s}: {scenario.epochs} epochs of {scenario.name}, seed {seed}"):
            summaries.append(simulate(scenario, strategy=s, seed=seed).summary())
    for summary in summaries:
        summary["scenario_file"] = str(args.scenario)
    if args.json:
        json.dump(summaries, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print_summaries(summaries, title=f"formation simulate {args.scenario} (seed {seed})")
    return 0


def register(sub: Any) -> None:
    p = sub.add_parser("simulate", help="run the model in one process (no Zenoh)")
    add_common(p)
    p.add_argument("--json", action="store_true", help="print the summaries as JSON")
    p.set_defaults(func=cmd_simulate)
