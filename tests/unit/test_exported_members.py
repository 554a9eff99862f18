"""Each service's root is its interface, in both directions (as httpx's test_exported_members).

What anyone takes from a service's root (or the shell's, the body's, the analysis') is in
that package's ``__all__``; and ``__all__`` is a promise to the product's other packages and
to a user's plug-ins (``examples/``), so each of its names is taken by one of them. The
benchmarks, the tests and their harness may reach inside a package (as its own tests do):
what only they take stays out of ``__all__``. That no module inside a service is imported from outside is the import
contract's (``lint-imports``, pyproject.toml); this test reads the checkout's sources.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import re
from collections import defaultdict
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SERVICES = ("agent", "leader", "netem", "recorder", "shell", "body", "analysis")
# Where code outside the services lives: the other product packages, benchmarks, examples, harness.
SOURCES = ("formation", *SERVICES, "testbed", "bench", "examples", "testkit/src/testkit", "tests")


def _owner(path: Path) -> str:
    """The package a source file belongs to; a service's own tests count as the service."""
    rel = path.relative_to(ROOT).parts
    if rel[0] == "tests" and len(rel) > 2 and rel[1] == "unit" and rel[2] in SERVICES:
        return rel[2]
    return rel[0]


# Who ``__all__`` is promised to: the product's packages and a user's plug-ins.
PROMISED_TO = {"formation", *SERVICES, "testbed", "examples"}
# and the seam a node's own tests run on (docs/architecture.md "Where to add": a node).
FOR_A_NODES_TESTS = {"shell": {"MemoryBus", "Lockstep", "Realtime"}}


def _taken() -> dict[str, dict[str, set[str]]]:
    """service → name → the files outside it that import the name from the service's root."""
    taken: dict[str, dict[str, set[str]]] = {s: defaultdict(set) for s in SERVICES}
    for source in SOURCES:
        for path in (ROOT / source).rglob("*.py"):
            owner = _owner(path)
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if (
                    isinstance(node, ast.ImportFrom)
                    and node.level == 0
                    and node.module in SERVICES
                    and node.module != owner
                ):
                    for alias in node.names:
                        taken[node.module][alias.name].add(str(path.relative_to(ROOT)))
    return taken


TAKEN = _taken()


def _package_of(file: str) -> str:
    return file.split("/", 1)[0]


def _isort_order(name: str) -> tuple[int, str]:
    """CONSTANTS, then Classes, then functions, each alphabetically."""
    return (0 if name.isupper() else 1 if name[0].isupper() else 2, name)


@pytest.mark.parametrize("service", SERVICES)
def test_all_is_sorted_and_there(service: str) -> None:
    package = importlib.import_module(service)
    assert package.__all__ == sorted(package.__all__, key=_isort_order)  # as ruff's RUF022 sorts
    missing = [n for n in package.__all__ if not hasattr(package, n)]
    assert not missing, f"{service}.__all__ names {missing}, which {service} does not have"


@pytest.mark.parametrize("service", SERVICES)
def test_what_others_take_is_exported(service: str) -> None:
    exported = set(importlib.import_module(service).__all__)
    outside = {n: sorted(f) for n, f in TAKEN[service].items() if n not in exported}
    assert not outside, f"taken from {service} but not in its __all__: {outside}"


def _returned(package: object) -> set[str]:
    """The names in the return annotations of a package's exported functions (their types)."""
    names: set[str] = set()
    for name in package.__all__:  # type: ignore[attr-defined]
        member = getattr(package, name)
        if inspect.isfunction(member):
            names |= set(re.findall(r"\w+", str(inspect.signature(member).return_annotation)))
    return names


@pytest.mark.parametrize("service", SERVICES)
def test_what_is_exported_is_taken(service: str) -> None:
    # A type that an exported function returns is offered with it (recorder.read_run's RunData).
    package = importlib.import_module(service)
    promised = {
        n for n, files in TAKEN[service].items() if {_package_of(f) for f in files} & PROMISED_TO
    }
    promised |= FOR_A_NODES_TESTS.get(service, set())
    unused = sorted(set(package.__all__) - promised - _returned(package))
    assert not unused, (
        f"{service}.__all__ names {unused}, which no package or plug-in outside {service} takes"
    )
