"""Each package's ``__init__`` exports what its ``__all__`` names."""

from __future__ import annotations

import importlib

import pytest

PACKAGES = ("formation", "shell", "agent", "leader", "netem", "recorder")


@pytest.mark.parametrize("name", PACKAGES)
def test_every_exported_name_is_there(name: str) -> None:
    package = importlib.import_module(name)
    assert package.__all__, f"{name}.__all__ is empty"
    missing = [n for n in package.__all__ if getattr(package, n, None) is None]
    assert not missing, f"{name}.__all__ names {missing}, which {name} does not have"
