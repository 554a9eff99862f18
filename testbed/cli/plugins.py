"""``formation plugins``: every loss strategy, controller and link model this install has."""

from __future__ import annotations

import argparse
import json
from typing import Any

from pydantic import BaseModel
from rich.markup import escape
from rich.table import Table

from formation.errors import PluginError, PluginKind
from formation.linkmodels import spec_class
from formation.plugin_api import control_law, loss_strategy
from formation.plugin_registry import GROUPS, registered
from testbed.cli.tables import print_table

TITLES = {"strategy": "loss strategies", "controller": "controllers", "link_model": "link models"}


def _parameters(model: type[BaseModel], skip: tuple[str, ...] = ()) -> list[str]:
    """``name: type = default`` (or ``name: type``, required) for each field of ``model``."""
    out = []
    for name, field in model.model_fields.items():
        if name in skip:
            continue
        ann = field.annotation
        kind = ann.__name__ if isinstance(ann, type) else str(ann).replace("typing.", "")
        shown = field.alias or name
        out.append(f"{shown}: {kind}" + ("" if field.is_required() else f" = {field.default!r}"))
    return out


def describe(kind: PluginKind, name: str) -> dict[str, Any]:
    """What ``formation plugins`` says of one plug-in; ``error`` when it cannot be loaded."""
    entry = registered(kind)[name]
    row: dict[str, Any] = {"kind": kind, "name": name, "package": entry.package}
    row["target"] = entry.target
    try:
        if kind == "strategy":
            strategy = loss_strategy(name)
            row["parameters"] = _parameters(strategy.params)
            row["description"] = strategy.description
        elif kind == "controller":
            law = control_law(name)
            row["parameters"] = _parameters(law.params)
            row["description"] = law.description
            row["dynamics"] = list(law.dynamics)
        else:
            spec = spec_class(name)
            row["parameters"] = _parameters(spec, skip=("model",))
            row["description"] = (spec.__doc__ or "").strip().splitlines()[0]
    except PluginError as exc:
        row["error"] = exc.problem
    return row


def cmd_plugins(args: argparse.Namespace) -> int:
    kinds: tuple[PluginKind, ...] = ("strategy", "controller", "link_model")
    rows = [describe(kind, name) for kind in kinds for name in registered(kind)]
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
    p.add_argument("--json", action="store_true", help="one JSON list instead of tables")
    p.set_defaults(func=cmd_plugins)
