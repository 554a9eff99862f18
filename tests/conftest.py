"""Shared fixtures: the repository's scenarios and a fixed seed.

The tests import the product as installed (``make test``), so the checkout is not on
``sys.path``; only ``tests/`` is made the ``tests`` package here, for ``tests.support``.
pytest's importlib mode has usually done so already (it imports test modules by their
rootdir-relative names, ``tests.unit....``), which pytest's documentation does not promise.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "scenarios"

if not hasattr(sys.modules.get("tests"), "__path__"):
    _spec = importlib.machinery.PathFinder.find_spec("tests", [str(ROOT)])
    assert _spec is not None, f"no tests package under {ROOT}"
    sys.modules["tests"] = importlib.util.module_from_spec(_spec)


@pytest.fixture
def seed() -> int:
    return 1


@pytest.fixture
def paper_path() -> Path:
    return SCENARIOS / "paper.toml"


@pytest.fixture
def paper(paper_path: Path):  # type: ignore[no-untyped-def]
    from formation.scenario import Scenario

    return Scenario.from_file(paper_path)
