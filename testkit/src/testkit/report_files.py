"""The files and paths a generated markdown report names, and which of them are missing."""

from __future__ import annotations

import re
from pathlib import Path

LINK = re.compile(r"\]\(([^)\s]+)\)")  # ![alt](file) and [text](file)
CODE = re.compile(r"`([^`\s]+)`")
PLAIN = re.compile(r"(?<![\w/`])((?:docs|scenarios|examples)/[\w./-]+\.\w+)")  # docs/model.md
FILE_LIKE = re.compile(r"\.(md|csv|png|mcap|toml|py|json)$")


def named(text: str) -> list[str]:
    """Every file ``text`` links or names: links, `code` ending in a file's extension, and
    the checkout's ``docs/``, ``scenarios/`` and ``examples/`` files named in plain text."""
    code = [c for c in CODE.findall(text) if FILE_LIKE.search(c)]
    return [*LINK.findall(text), *code, *PLAIN.findall(text)]


def missing(report: Path, checkout: Path) -> list[str]:
    """What ``report`` names that exists neither beside it, nor from the working folder,
    nor in the ``checkout`` (an absolute path: where it says)."""
    bases = (report.parent, Path.cwd(), checkout)
    names = named(report.read_text(encoding="utf-8"))
    return [p for p in names if not _exists(Path(p), bases)]


def _exists(path: Path, bases: tuple[Path, ...]) -> bool:
    if path.is_absolute():
        return path.exists()
    return any((base / path).exists() for base in bases)


__all__ = ["missing", "named"]
