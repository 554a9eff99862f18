"""Summary tables keep every number whole off a terminal, and fit the terminal on one."""

from __future__ import annotations

import io

from rich.console import Console
from rich.table import Table

from testbed.cli.tables import print_table


def _wide_table() -> Table:
    table = Table(title="summary")
    for col in ("strategy", "formation\nfinal [m]", "links with drops\n(sent/dropped)") * 3:
        table.add_column(col)
    table.add_row(*("estimate", "0.0012345", "1->2 50/49, 2->1 50/49") * 3)
    return table


def test_off_a_terminal_the_table_gets_the_width_it_needs() -> None:
    out = io.StringIO()
    print_table(_wide_table(), Console(file=out, width=80))
    text = out.getvalue()
    assert "…" not in text
    assert text.count("0.0012345") == 3 and text.count("(sent/dropped)") == 3
    assert max(len(line) for line in text.splitlines()) > 80


def test_on_a_terminal_the_table_fits_its_width() -> None:
    out = io.StringIO()
    print_table(_wide_table(), Console(file=out, width=80, force_terminal=True, color_system=None))
    assert max(len(line) for line in out.getvalue().splitlines()) <= 80
