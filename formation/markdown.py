"""Markdown tables: one writer, so every table of a report or a study has the same form."""

from __future__ import annotations

from collections.abc import Iterable, Sequence


def row(cells: Iterable[object]) -> str:
    """One line of a table: ``| a | b |``."""
    return "| " + " | ".join(str(c) for c in cells) + " |"


def table(header: Sequence[str], rows: Iterable[Iterable[object]]) -> str:
    """A markdown table: ``header``, its separator, one line per row; ends with a newline."""
    lines = [row(header), row("---" for _ in header), *(row(r) for r in rows)]
    return "\n".join(lines) + "\n"


__all__ = ["row", "table"]
