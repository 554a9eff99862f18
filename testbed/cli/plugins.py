"""``formation plugins``: every loss strategy, controller and link model this install has."""

from __future__ import annotations

import argparse
import json
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from rich.markup import escape
from rich.table import Table

from formation.errors import PluginError, PluginKind
from formation.plugin_registry import GROUPS, find, registered
from testbed.cli.tables import print_table

if TYPE_CHECKING:
    from pydantic import BaseModel
    from pydantic.fields import FieldInfo

    from formation.scenario import Scenario

TITLES = {"strategy": "loss strategies", "controller": "controllers", "link_model": "link models"}


_BOUNDS = {"gt": ">", "ge": ">=", "lt": "<", "le": "<=", "multiple_of": "a multiple of"}
_LENGTHS = {"min_length": "length >=", "max_length": "length <="}


def _allowed(field: FieldInfo) -> str:
    """The rules pydantic checks on a field's value: ``> 0, <= 1``, ``length >= 1``."""
    rules = []
    for rule in field.metadata:
        for attr, word in _BOUNDS.items():
            if getattr(rule, attr, None) is not None:
                rules.append(f"{word} {getattr(rule, attr)!r}")
        for attr, word in _LENGTHS.items():
            if getattr(rule, attr, None) is not None:
                rules.append(f"{word} {getattr(rule, attr)!r}")
    return ", ".join(rules)


def _parameters(
    model: type[BaseModel], skip: tuple[str, ...] = (), values: dict[str, Any] | None = None
) -> list[str]:
    """``name: type = default (rules)`` (or ``name: type``, required) for each field of
    ``model``; with ``values`` (a scenario's), ``name: type = value [scenario|default]``."""
    out = []
    for name, field in model.model_fields.items():
        if name in skip:
            continue
        ann = field.annotation
        kind = ann.__name__ if isinstance(ann, type) else str(ann).replace("typing.", "")
        shown = field.alias or name
        line = f"{shown}: {kind}"
        if values is not None:
            value, source = values[shown]
            line += f" = {value!r} [{source}]"
        elif not field.is_required():
            line += f" = {field.default!r}"
        rules = _allowed(field)
        out.append(line + (f" ({rules})" if rules else ""))
    return out


def _first_line(doc: str | None) -> str:
    """A docstring's first line; empty for a class without one."""
    lines = (doc or "").strip().splitlines()
    return lines[0] if lines else ""


def _scenario_values(params: BaseModel, sources: Mapping[str, str]) -> dict[str, tuple[Any, str]]:
    """Each parameter's value as the scenario runs it, and where it came from."""
    dumped = params.model_dump(mode="json", by_alias=True)
    return {shown: (dumped[shown], source) for shown, source in sources.items()}


def describe(kind: PluginKind, name: str, scenario: Scenario | None = None) -> dict[str, Any]:
    """What ``formation plugins`` says of one plug-in; ``error`` when it cannot be loaded.
    With ``scenario``, a strategy's or a controller's parameters are the values it runs with,
    each marked ``default`` (the plug-in's own) or ``scenario`` (its table in the file)."""
    from formation.linkmodels import spec_class  # here: `formation plugins --help` is light
    from formation.plugin_api import control_law, loss_strategy

    entry = find(kind, name)
    row: dict[str, Any] = {"kind": kind, "name": name, "package": entry.package}
    row["target"] = entry.target
    try:
        values = None
        if kind == "strategy":
            strategy = loss_strategy(name)
            if scenario is not None:
                s = scenario.strategy
                values = _scenario_values(s.params_of(name), s.sources_of(name))
            row["parameters"] = _parameters(strategy.params, values=values)
            row["description"] = strategy.description
        elif kind == "controller":
            law = control_law(name)
            if scenario is not None:
                c = scenario.control
                values = _scenario_values(c.params_of(name), c.sources_of(name))
            row["parameters"] = _parameters(law.params, values=values)
            row["description"] = law.description
            row["dynamics"] = list(law.dynamics)
        else:
            spec = spec_class(name)
            row["parameters"] = _parameters(spec, skip=("model",))
            row["description"] = _first_line(spec.__doc__)
        if values is not None:
            row["values"] = {k: {"value": v, "from": src} for k, (v, src) in values.items()}
    except PluginError as exc:
        row["error"] = exc.problem
    return row


def _names(kind: PluginKind, scenario: Scenario | None) -> list[str]:
    """The registered plug-ins of ``kind``, then those the scenario names by import path."""
    found = list(registered(kind))
    if scenario is not None and kind != "link_model":
        if kind == "strategy":
            named = [scenario.strategy.name, *scenario.strategy.params]
        else:
            named = [scenario.control.controller, *scenario.control.params]
        found += [n for n in named if n not in found]
    return found


def cmd_plugins(args: argparse.Namespace) -> int:
    kinds: tuple[PluginKind, ...] = ("strategy", "controller", "link_model")
    from testbed.cli.arguments import load_checked  # only with a scenario: it loads netem

    scenario = None if args.scenario is None else load_checked(args.scenario)
    rows = [describe(kind, name, scenario) for kind in kinds for name in _names(kind, scenario)]
    if args.json:
        print(json.dumps(rows, indent=2))
    else:
        for kind in kinds:
            table = Table(title=f"{TITLES[kind]} (entry-point group {GROUPS[kind]})")
            for col in ("name", "package", "parameters", "description"):
                table.add_column(col, overflow="fold")
            for r in (r for r in rows if r["kind"] == kind):
                about = r.get("description", "")
                if "dynamics" in r:
                    about += f" [dynamics: {', '.join(r['dynamics'])}]"
                if "error" in r:
                    about = f"[red]cannot be used: {escape(r['error'])}[/]"
                params = "\n".join(r.get("parameters", []))
                if "error" not in r:
                    about = escape(about)
                table.add_row(r["name"], r["package"], escape(params), about)
            print_table(table)
    return 1 if any("error" in r for r in rows) else 0


def register(sub: Any) -> None:
    p = sub.add_parser(
        "plugins",
        help="list every loss strategy, controller and link model, built-in or installed",
    )
    p.add_argument(
        "scenario",
        nargs="?",
        help="a scenario file: show each strategy's and controller's parameters as it runs "
        "them, each marked [default] (the plug-in's own) or [scenario] (set in the file)",
    )
    p.add_argument("--json", action="store_true", help="one JSON list instead of tables")
    p.set_defaults(func=cmd_plugins)
