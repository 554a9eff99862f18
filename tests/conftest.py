"""Shared fixtures: the repository's scenarios and a fixed seed.

The tests import the product as installed (``make test``), so the checkout is not on
``sys.path``; what they share with the benchmarks is the installed ``testkit`` package,
and no test module imports another.
"""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "scenarios"


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
