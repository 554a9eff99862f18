"""Terminal tables of run summaries, with rich."""

from __future__ import annotations

from typing import Any

from rich.console import Console
from rich.table import Table
from rich.text import Text


def print_table(table: Table, console: Console | None = None) -> None:
    """Print ``table`` whole. Off a terminal (a pipe, a log file, CI) rich assumes 80 columns
    and cuts cells to "0.28…"; there the table gets the width it needs instead."""
    console = console or Console()
    if not console.is_terminal:
        natural = console.measure(table, options=console.options.update_width(10_000)).maximum
        if natural > console.width:
            console = Console(file=console.file, width=natural)
    console.print(table)


def header(col: str) -> Text:
    """A column header as plain text: rich would take its unit, "[m]", for a markup tag."""
    return Text(col)


def _fmt(v: Any, spec: str = ".3g") -> str:
    return "-" if v is None else format(v, spec)


# Columns that name what a row is; every other column's header ends in its unit, "[m]".
LABELS = ("strategy", "seed", "epochs", "link", "topic", "schema")

SUMMARY_COLUMNS = (
    "strategy",
    "seed",
    "epochs",
    "formation\nfinal [m]",
    "formation\npeak [m]",
    "shape\nfinal [m]",
    "subst.\ncov tr [m²]",
    "hold fall-\nbacks [pkts]",
    "estim.\ncov tr [m²]",
    "mean\nNEES [-]",
    "min dist\n[m]",
    "colli-\nsions [#]",
)


def print_summaries(
    summaries: list[dict[str, Any]], title: str, console: Console | None = None
) -> None:
    """One row per run: formation/shape error, substitution and estimation figures."""
    table = Table(title=title)
    for col in SUMMARY_COLUMNS:
        table.add_column(
            header(col), justify="right" if col != "strategy" else "left", no_wrap=True
        )
    for s in summaries:
        table.add_row(
            s["strategy"],
            str(s["seed"]),
            str(s["epochs"]),
            _fmt(s["final_formation_error_m"]),
            _fmt(s["peak_formation_error_m"]),
            _fmt(s["final_shape_error_m"]),
            _fmt(s["substitution_cov_trace_m2"]),
            str(s["fallbacks"]),
            _fmt(s["estimation_cov_trace_m2"]),
            _fmt(s["nees_mean"], ".3f"),
            _fmt(s["safety"]["min_distance_m"]),
            str(s["safety"]["collisions_total"]),
        )
    print_table(table, console)
