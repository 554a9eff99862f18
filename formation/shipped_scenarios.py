"""The scenarios shipped inside the package, and how a name or a path becomes a scenario file.

A scenario is given as a path (``my/team.toml``) or as the name of a shipped one (``paper``,
``large/team10k``): a path that exists wins, so a local file is never shadowed. The files sit
in ``formation/scenarios/`` (package data, in the wheel); the checkout's top-level
``scenarios`` points there for compose files, tests and docs.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

from formation.errors import NO_VALUE, ScenarioError

SHIPPED_DIR = Path(__file__).parent / "scenarios"
SUFFIX = ".toml"


def shipped() -> dict[str, Path]:
    """Every shipped scenario by name (its path under ``scenarios/`` without ``.toml``), sorted."""
    files = sorted(SHIPPED_DIR.rglob(f"*{SUFFIX}"))
    return {f.relative_to(SHIPPED_DIR).with_suffix("").as_posix(): f for f in files}


def resolve(name_or_path: str | Path) -> Path:
    """The file of ``name_or_path``: the path itself when it exists or ends in ``.toml``, else
    the shipped scenario of that name; an unknown name is refused with the shipped ones listed."""
    path = Path(name_or_path)
    if path.exists() or path.suffix == SUFFIX:
        return path
    found = shipped()
    key = path.as_posix()
    if key in found:
        return found[key]
    names = ", ".join(found)
    raise ScenarioError(
        str(name_or_path),
        "",
        NO_VALUE,
        f"no such file, nor a shipped scenario of that name; shipped: {names} "
        "(`formation scenarios` describes them)",
    )


# A table header (``[control]``, ``[[agents]]``): TOML puts every top-level key before the first.
_TABLE = re.compile(r"^\s*\[\[?\s*[A-Za-z_\"']", re.MULTILINE)


def description(path: Path) -> str:
    """The ``description`` field of a scenario file, not validated; "" if none. Only the part
    before the first table is parsed: a team of thousands of agents lists in milliseconds."""
    text = path.read_text(encoding="utf-8")
    table = _TABLE.search(text)
    try:
        value = tomllib.loads(text[: table.start()] if table else text).get("description", "")
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(str(path), "", NO_VALUE, f"TOML syntax error: {exc}") from None
    return value if isinstance(value, str) else ""


__all__ = ["SHIPPED_DIR", "description", "resolve", "shipped"]
