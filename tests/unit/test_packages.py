"""Each package's ``__init__`` exports what its ``__all__`` names."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

PACKAGES = ("formation", "shell", "body", "analysis", "agent", "leader", "netem", "recorder")


@pytest.mark.parametrize("name", PACKAGES)
def test_every_exported_name_is_there(name: str) -> None:
    package = importlib.import_module(name)
    assert package.__all__, f"{name}.__all__ is empty"
    missing = [n for n in package.__all__ if getattr(package, n, None) is None]
    assert not missing, f"{name}.__all__ names {missing}, which {name} does not have"


def test_no_test_module_imports_another() -> None:
    # What tests share lives in the testkit package, so that tests/ needs no package of its own.
    tests = Path(__file__).resolve().parents[1]
    found = [
        f"{path.relative_to(tests)}: {node.module}"
        for path in tests.rglob("*.py")
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
        if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "tests"
    ]
    assert not found, found
