"""``formation simulate``: the model in one process, no Zenoh."""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING, Any

from formation.errors import TestbedError
from testbed.cli.arguments import add_common, load_checked, scenario_strategies
from testbed.cli.progress import Stages

if TYPE_CHECKING:
    from testbed.sim.result import SimResult

CLASSES = ("formation", "report", "estimate")  # the link classes, as netem's records name them


def decisions_by_epoch(result: SimResult) -> list[dict[str, Any]]:
    """Each epoch's packets the model passed (counts) and dropped (links), by link class: a
    formation link as ``[src, dst]``, a control link by its agent (``report``: agent → leader,
    ``estimate``: leader → agent)."""
    import numpy as np  # here: `formation simulate --help` loads no numerics

    d = result.decisions_made()
    dropped = d.verdict == "drop"
    out = []
    for k in range(len(result.delivered)):
        at = d.epoch == k
        row: dict[str, Any] = {"epoch": k, "passed": {}, "dropped": {}}
        for name in CLASSES:
            mine = at & (d.link_class == name)
            lost = mine & dropped
            row["passed"][name] = int(np.count_nonzero(mine & ~dropped))
            if name == "formation":
                row["dropped"][name] = np.stack([d.source[lost], d.target[lost]], 1).tolist()
            else:
                agent = d.source if name == "report" else d.target
                row["dropped"][name] = agent[lost].tolist()
        out.append(row)
    return out


def cmd_simulate(args: argparse.Namespace) -> int:
    from testbed.cli.tables import print_summaries
    from testbed.sim.simulate import simulate

    if args.decisions and not args.json:
        raise TestbedError("--decisions: give it with --json (the tables stay compact)")
    scenario = load_checked(args.scenario)
    if args.epochs is not None:
        scenario = scenario.with_overrides(epochs=args.epochs)
    seed = scenario.seed if args.seed is None else args.seed
    strategies = scenario_strategies(args.strategy, scenario)
    stages = Stages("formation simulate", len(strategies))
    summaries = []
    for s in strategies:
        with stages.stage(f"{s}: {scenario.epochs} epochs of {scenario.name}, seed {seed}"):
            result = simulate(scenario, strategy=s, seed=seed)
            summary = result.summary()
        summary["scenario_file"] = str(args.scenario)
        if args.decisions:
            summary["decisions"] = decisions_by_epoch(result)
        summaries.append(summary)
    if args.json:
        json.dump(summaries, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print_summaries(summaries, title=f"formation simulate {args.scenario} (seed {seed})")
        for summary in summaries:
            if "air_losses" in summary:  # the shared air (docs/model.md §11)
                lost = ", ".join(
                    f"{v} {k.replace('_', ' ')}" for k, v in summary["air_losses"].items()
                )
                print(f"{summary['strategy']}: lost on the air: {lost}")
    return 0


def register(sub: Any) -> None:
    p = sub.add_parser("simulate", help="run the model in one process (no Zenoh)")
    add_common(p)
    p.add_argument("--json", action="store_true", help="print the summaries as JSON")
    p.add_argument(
        "--decisions",
        action="store_true",
        help="with --json: each summary's 'decisions', one entry per epoch: the packets the "
        "link models passed (counts) and dropped ([src, dst] formation links; report and "
        "estimate control links by agent), by link class",
    )
    p.set_defaults(func=cmd_simulate)
