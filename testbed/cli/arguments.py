"""What the subcommands share: the default scenario, ``--strategy`` and the common arguments."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from formation.scenario import Scenario

# A shipped scenario's name (formation/shipped_scenarios.py): it resolves from any folder.
DEFAULT_SCENARIO = "paper"
SCENARIO_HELP = (
    "a shipped scenario's name (`formation scenarios` lists them) or a scenario TOML file "
    f"(default: {DEFAULT_SCENARIO})"
)


def parse_strategies(
    arg: str | None, default: Sequence[Any], named: dict[str, Sequence[Any]] | None = None
) -> list[Any]:
    """``--strategy``: ``None`` → ``default``; ``all`` (every registered strategy), another
    name in ``named``, or ``a,b,...`` (registered names or ``package.module:name``)."""
    from formation.errors import TestbedError
    from formation.plugin_api import all_strategies
    from formation.plugin_registry import is_reference

    if arg is None:
        return list(default)
    known = all_strategies()
    choices = {"all": known, **(named or {})}
    if arg in choices:
        return list(choices[arg])
    names = [s.strip() for s in arg.split(",")]
    for name in names:
        if name not in known and not is_reference(name):
            words = ", ".join(sorted(choices))
            raise TestbedError(
                f"--strategy {name!r}: expected one of {', '.join(known)}, "
                f"a 'package.module:name', or {words}"
            )
    return names


def load_checked(path: str, epochs: int | None = None) -> Scenario:
    """The scenario ``path`` (a file, or a shipped scenario's name) with ``--epochs``, its link
    models' layers built and run on a few epochs: a plug-in's mistake is refused here, naming
    the file and the field."""
    from formation.errors import PluginFailure, ScenarioError, TestbedError
    from formation.scenario import Scenario
    from netem import probe_stack

    scenario = Scenario.from_file(path)
    for field, models in scenario.model_stacks():
        try:
            probe_stack(models, field)
        except (PluginFailure, TestbedError) as exc:
            tags = [m.model for m in models]
            raise ScenarioError(path, field, tags, f"on a probe of 8 epochs: {exc}") from None
    return scenario if epochs is None else scenario.with_overrides(epochs=epochs)


def scenario_strategies(arg: str | None, scenario: Scenario) -> list[Any]:
    """``--strategy`` for a scenario: its own strategy when none is given. Each is checked
    with the scenario (its parameters, a probe call) before anything runs."""
    from formation.errors import ScenarioError, TestbedError

    names = parse_strategies(arg, [scenario.strategy.name])
    for name in names:
        if name != scenario.strategy.name:
            try:
                scenario.with_strategy(name)
            except ScenarioError as exc:
                raise TestbedError(f"--strategy {name!r}: {exc.problem}") from None
    return names


class StrategiesHelp(str):
    """A help text whose ``{strategies}`` is every installed loss strategy, looked up when the
    help is shown (argparse formats it with ``%``), not each time the parser is built."""

    __slots__ = ()

    def __mod__(self, params: Any) -> str:
        from formation.plugin_registry import all_strategies  # entry points, not imported

        names = ", ".join(all_strategies()).replace("%", "%%")
        return str(str(self).replace("{strategies}", names) % params)


def add_common(p: argparse.ArgumentParser) -> None:
    """The scenario, ``--strategy``, ``--seed`` and ``--epochs``."""
    p.add_argument("scenario", nargs="?", default=DEFAULT_SCENARIO, help=SCENARIO_HELP)
    p.add_argument(
        "--strategy",
        help=StrategiesHelp(
            "the scenario's (default), one of {strategies}, a 'package.module:name', "
            "a comma list of them, or all"
        ),
    )
    p.add_argument("--seed", type=int, help="overrides the scenario's seed")
    p.add_argument("--epochs", type=int, help="overrides the scenario's epochs")
