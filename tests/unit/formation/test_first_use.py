"""Package roots that load their names on first use (formation.first_use)."""

from __future__ import annotations

import subprocess
import sys

import pytest

import shell
import testbed


def test_an_unknown_name_is_an_attribute_error_naming_the_package() -> None:
    with pytest.raises(AttributeError, match="module 'testbed' has no attribute 'nothing'"):
        _ = testbed.nothing  # type: ignore[attr-defined]
    assert not hasattr(shell, "nothing")


def test_a_name_loads_its_module_once_and_is_then_a_plain_attribute() -> None:
    code = (
        "import sys, testbed\n"
        "assert 'testbed.sim.team_generators' not in sys.modules\n"
        "first = testbed.rigid_team\n"
        "assert 'testbed.sim.team_generators' in sys.modules\n"
        "assert 'rigid_team' in vars(testbed) and testbed.rigid_team is first\n"
        "from formation.scenario import load\n"
        "assert testbed.load_scenario is load  # a name its module spells otherwise\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
