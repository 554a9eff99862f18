"""What the subcommands share: the default scenario, ``--strategy`` and the common arguments."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
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


def scenario_strategies(arg: str | None, scenario: Scenario) -> list[Any]:
    """``--strategy`` for a scenario: its own strategy when none is given."""
    return parse_strategies(arg, [scenario.strategy.name])


def add_common(
    p: argparse.ArgumentParser, strategy_help: str = "zero|hold|estimate|blend|drop|all"
) -> None:
    """The scenario file, ``--strategy``, ``--seed`` and ``--epochs``."""
    p.add_argument("scenario", nargs="?", default=DEFAULT_SCENARIO, help="scenario TOML file")
    p.add_argument("--strategy", help=strategy_help)
    p.add_argument("--seed", type=int, help="overrides the scenario's seed")
    p.add_argument("--epochs", type=int, help="overrides the scenario's epochs")
