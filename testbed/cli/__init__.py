"""The ``formation`` command: one subcommand per job; each prints a clear error and exits 1 on bad input."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Sequence
from typing import Any

from formation.errors import TestbedError
from formation.scenario import STRATEGIES, Scenario

DEFAULT_SCENARIO = "scenarios/paper.toml"


def parse_strategies(
    arg: str | None, default: Sequence[Any], named: dict[str, Sequence[Any]] | None = None
) -> list[Any]:
    """``--strategy``: ``None`` → ``default``; ``all``, another name in ``named``, or ``a,b,...``."""
    if arg is None:
        return list(default)
    choices = {"all": STRATEGIES, **(named or {})}
    if arg in choices:
        return list(choices[arg])
    names = [s.strip() for s in arg.split(",")]
    for name in names:
        if name not in STRATEGIES:
            words = ", ".join(sorted(choices))
            raise TestbedError(
                f"--strategy {name!r}: expected one of {', '.join(STRATEGIES)} or {words}"
            )
    return names


def _strategies(arg: str | None, scenario: Scenario) -> list[Any]:
    return parse_strategies(arg, [scenario.strategy.name])


def cmd_simulate(args: argparse.Namespace) -> int:
    from testbed.simulate import simulate
    from testbed.tables import print_summaries

    scenario = Scenario.from_file(args.scenario)
    if args.epochs is not None:
        scenario = scenario.with_overrides(epochs=args.epochs)
    seed = scenario.seed if args.seed is None else args.seed
    summaries = [
        simulate(scenario, strategy=s, seed=seed).summary()
        for s in _strategies(args.strategy, scenario)
    ]
    for s in summaries:
        s["scenario_file"] = str(args.scenario)
    if args.json:
        json.dump(summaries, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print_summaries(summaries, title=f"formation simulate {args.scenario} (seed {seed})")
    return 0


def _add_common(
    p: argparse.ArgumentParser, strategy_help: str = "zero|hold|estimate|blend|drop|all"
) -> None:
    p.add_argument("scenario", nargs="?", default=DEFAULT_SCENARIO, help="scenario TOML file")
    p.add_argument("--strategy", help=strategy_help)
    p.add_argument("--seed", type=int, help="overrides the scenario's seed")
    p.add_argument("--epochs", type=int, help="overrides the scenario's epochs")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="formation",
        description="Formation control over packet-dropping links: simulate, run, record, analyse.",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("simulate", help="run the model in one process (no Zenoh)")
    _add_common(p)
    p.add_argument("--json", action="store_true", help="print the summaries as JSON")
    p.set_defaults(func=cmd_simulate)
    for register in _extra_commands():
        register(sub)
    return parser


def _extra_commands() -> list[Callable[[Any], None]]:
    """Subcommands that live in their own modules (run, report, replay, ...)."""
    from testbed import deploy_cli, experiment_cli, netem_cli, recorder_cli, run_cli

    return [
        run_cli.register,
        netem_cli.register,
        recorder_cli.register,
        deploy_cli.register,
        experiment_cli.register,
    ]


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        code: int = args.func(args)
    except TestbedError as exc:
        print(f"formation {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"formation {args.command}: interrupted", file=sys.stderr)
        return 130
    return code


if __name__ == "__main__":
    sys.exit(main())


__all__ = ["build_parser", "main"]
