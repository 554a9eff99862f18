"""``formation plugins``: every plug-in listed with its rules, and a scenario's values with
where each came from."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from testbed.cli import main
from testbed.cli.plugins import describe

ROOT = Path(__file__).resolve().parents[3]
BAD = ROOT / "tests" / "data" / "plugins"

IMPORTS = """\
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import Field

from formation.linkmodels import Spec
from netem import Keys, Layer, LayerOutput
"""


def test_the_docs_jammer_without_a_docstring_is_listed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    docs = (ROOT / "docs" / "plugins.md").read_text()
    (block,) = [b for b in re.findall(r"```python\n(.*?)```", docs, re.S) if "class Jammer(" in b]
    (tmp_path / "docs_jammer.py").write_text(IMPORTS + block)
    monkeypatch.syspath_prepend(str(tmp_path))
    row = describe("link_model", "docs_jammer:Jammer")
    assert "error" not in row, row
    assert row["description"] == ""
    assert row["parameters"][0] == "links: tuple[tuple[int, int], ...] (length >= 1)"
    assert "start: int = 0 (>= 0)" in row["parameters"]


def test_each_parameter_shows_its_allowed_range() -> None:
    assert describe("strategy", "blend")["parameters"] == ["alpha: float = 0.5 (> 0.0, <= 1.0)"]
    assert describe("link_model", "bernoulli")["parameters"][0] == "p_loss: float (>= 0.0, <= 1.0)"


def test_with_a_scenario_each_value_says_where_it_came_from(
    paper_path: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.syspath_prepend(str(BAD))
    scenario = tmp_path / "own_alpha.toml"
    text = paper_path.read_text().replace('name = "estimate"', 'name = "bad_plugins:OWN_ALPHA"')
    scenario.write_text(text + "\n[strategy.params.blend]\nalpha = 0.3\n")
    assert main(["plugins", str(scenario), "--json"]) == 0
    rows = {(r["kind"], r["name"]): r for r in json.loads(capsys.readouterr().out)}
    own = rows["strategy", "bad_plugins:OWN_ALPHA"]
    assert own["values"] == {"alpha": {"value": 0.9, "from": "default"}}
    assert own["parameters"] == ["alpha: float = 0.9 [default] (> 0.0, <= 1.0)"]
    assert rows["strategy", "blend"]["values"] == {"alpha": {"value": 0.3, "from": "scenario"}}
    assert rows["strategy", "extrapolate"]["values"]["horizon_epochs"]["from"] == "default"


@pytest.mark.parametrize("command", ["simulate", "run", "sweep"])
def test_strategy_help_lists_the_installed_plugins(
    command: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("COLUMNS", "200")
    assert main([command, "--help"]) == 0
    said = " ".join(capsys.readouterr().out.split())
    assert "zero, hold, estimate, blend, drop, extrapolate" in said  # the example's is installed
