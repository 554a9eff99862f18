"""``formation scenarios``: the shipped scenarios, by the name every command takes."""

from __future__ import annotations

import argparse
import json
from typing import Any


def cmd_scenarios(args: argparse.Namespace) -> int:
    from rich.table import Table

    from formation.shipped_scenarios import description, shipped
    from testbed.cli.tables import print_table

    rows = [
        {"name": name, "description": description(path), "path": str(path)}
        for name, path in shipped().items()
    ]
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    table = Table(title="shipped scenarios (give the name, or a path to your own TOML file)")
    for col in ("name", "description"):
        table.add_column(col, overflow="fold", no_wrap=col == "name")
    for row in rows:
        table.add_row(row["name"], row["description"] or "-")
    print_table(table)
    return 0


def register(sub: Any) -> None:
    p = sub.add_parser(
        "scenarios", help="list the shipped scenarios, by the name the other commands take"
    )
    p.add_argument(
        "--json", action="store_true", help="one JSON list (name, description, path) instead"
    )
    p.set_defaults(func=cmd_scenarios)


__all__ = ["register"]
