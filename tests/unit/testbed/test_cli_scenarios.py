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


def test_an_unknown_name_is_a_clear_error_naming_the_shipped_ones(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["simulate", "papr"]) == 1
    out, err = capsys.readouterr()
    assert out == "" and err.startswith("formation simulate: error: papr: no such file, nor a")
    assert (
        "shipped: access_point, distance_rigidity, distance_rigidity_fast, events, grid20, large/team10k, octahedron3d, paper"
        in err
    )


def test_formation_scenarios_lists_each_with_its_description(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["scenarios", "--json"]) == 0
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    assert {"paper", "ring8", "grid20", "large/team10k"} <= set(rows)
    assert rows["paper"]["description"].startswith("Seshadhri & Ayyagari")
    assert Path(rows["paper"]["path"]).is_file()
    assert main(["scenarios"]) == 0
    table = capsys.readouterr().out
    assert "large/team10k" in table and "Eight agents on a ring" in table
