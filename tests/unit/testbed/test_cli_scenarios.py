"""The installed ``formation`` from a folder that is not the checkout: shipped names resolve."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from testbed.cli import main

FORMATION = str(Path(sys.executable).parent / "formation")


def _formation(*argv: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [FORMATION, *argv], capture_output=True, text=True, cwd=cwd, timeout=300, check=False
    )


def test_simulate_a_shipped_name_from_another_folder(tmp_path: Path) -> None:
    done = _formation("simulate", "paper", "--epochs", "3", "--json", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    (summary,) = json.loads(done.stdout)
    assert (summary["scenario"], summary["epochs"], summary["scenario_file"]) == (
        "paper",
        3,
        "paper",
    )


def test_an_unknown_name_is_a_clear_error_naming_the_shipped_ones(tmp_path: Path) -> None:
    done = _formation("simulate", "papr", cwd=tmp_path)
    assert done.returncode == 1 and done.stdout == ""
    assert done.stderr.startswith("formation simulate: error: papr: no such file, nor a shipped")
    assert "paper" in done.stderr and "Traceback" not in done.stderr


def test_formation_scenarios_lists_each_with_its_description(tmp_path: Path) -> None:
    done = _formation("scenarios", "--json", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    rows = {r["name"]: r for r in json.loads(done.stdout)}
    assert {"paper", "ring8", "grid20", "large/team10k"} <= set(rows)
    assert rows["paper"]["description"].startswith("Seshadhri & Ayyagari")
    assert Path(rows["paper"]["path"]).is_file()


def test_the_scenarios_table_names_and_describes_each(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["scenarios"]) == 0
    out = capsys.readouterr().out
    assert "large/team10k" in out and "Eight agents on a ring" in out
