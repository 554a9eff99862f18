"""The shipped scenarios are package data: a bare name resolves to one, a path still works."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from formation.errors import ScenarioError
from formation.scenario import Scenario
from formation.shipped_scenarios import description, resolve, shipped

CHECKOUT = Path(__file__).resolve().parents[3] / "scenarios"


def test_the_installed_package_ships_every_scenario_of_the_checkout() -> None:
    files = sorted(CHECKOUT.rglob("*.toml"))
    names = [f.relative_to(CHECKOUT).with_suffix("").as_posix() for f in files]
    assert list(shipped()) == names and "paper" in names and "large/team10k" in names
    for name, f in zip(names, files, strict=True):
        assert shipped()[name].read_bytes() == f.read_bytes(), name


def test_a_name_loads_the_shipped_scenario_from_any_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    assert resolve("paper") == shipped()["paper"]
    assert Scenario.from_file("paper") == Scenario.from_file(CHECKOUT / "paper.toml")
    assert resolve("large/team10k") == shipped()["large/team10k"]


def test_a_path_that_exists_wins_over_a_shipped_name(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "paper").write_text((CHECKOUT / "ring8.toml").read_text())
    assert resolve("paper") == Path("paper")
    assert Scenario.from_file("paper").name == "ring8"


def test_an_unknown_name_is_refused_listing_the_shipped_ones() -> None:
    with pytest.raises(ScenarioError, match=r"^papr: no such file, nor a shipped scenario") as exc:
        Scenario.from_file("papr")
    assert (
        "shipped: access_point, distance_rigidity, distance_rigidity_fast, events, grid20, large/team10k"
        in str(exc.value)
    )


def test_a_missing_toml_file_is_a_path_not_a_name(tmp_path: Path) -> None:
    missing = tmp_path / "paper.toml"
    with pytest.raises(ScenarioError, match=r"paper\.toml: cannot read the file"):
        Scenario.from_file(missing)


def test_every_shipped_scenario_has_its_one_line_description() -> None:
    for name, path in shipped().items():
        whole = tomllib.loads(path.read_text())
        assert description(path) == whole["description"] != "", name
        assert "\n" not in description(path), name
