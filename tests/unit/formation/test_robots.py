"""Robot and wireless settings of a scenario: defaults, and bad input naming file, field and value."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from formation.errors import ScenarioError
from formation.robots import initial_headings
from formation.scenario import load
from testkit.scenario_files import TRIANGLE, scenario_file


def write(tmp_path: Path, text: str) -> Path:
    return scenario_file(tmp_path, TRIANGLE + text)


def test_defaults_are_a_small_ground_robot(tmp_path: Path) -> None:
    s = load(write(tmp_path, ""))
    uni = s.control.unicycle
    assert (uni.max_speed_m_s, uni.max_turn_rad_s) == (0.2, 3.6)
    assert s.safety.body_diameter_m == 0.1 and s.safety.bounds is None
    assert s.network.access_point is None


def test_a_wireless_unicycle_scenario_loads(tmp_path: Path) -> None:
    s = load(
        write(
            tmp_path,
            """
[control]
dynamics = "unicycle"
controller = "distance"
[control.unicycle]
max_speed_m_s = 0.3
[network]
access_point = [0.0, 0.0]
formation_default = [{model = "logistic", d50_m = 1.5, width_m = 0.2}]
control_default = [{model = "range", max_range_m = 10.0}]
[safety]
body_diameter_m = 0.2
bounds = {min_m = [-2.0, -2.0], max_m = [2.0, 2.0]}
""",
        )
    )
    assert s.control.unicycle.max_speed_m_s == 0.3
    assert s.formation_link_models(1, 2)[0].model == "logistic"


@pytest.mark.parametrize(
    ("text", "pattern"),
    [
        (
            '[network]\nformation_default = [{model = "range", max_range_m = 0.0}]',
            r"bad\.toml: network\.formation_default\[0\]\.max_range_m = 0\.0; .*greater than 0",
        ),
        (
            '[network]\nformation_default = [{model = "range", max_range_m = -3}]',
            r"bad\.toml: network\.formation_default\[0\]\.max_range_m = -3; .*greater than 0",
        ),
        (
            '[[network.links]]\nbetween = [1, 2]\nmodels = [{model = "logistic", d50_m = 1.0, width_m = 0}]',
            r"bad\.toml: network\.links\[0\]\.models\[0\]\.width_m = 0; .*greater than 0",
        ),
        (
            '[control]\ndynamics = "unicycle"\n[control.unicycle]\nmax_speed_m_s = 0',
            r"bad\.toml: control\.unicycle\.max_speed_m_s = 0; .*greater than 0",
        ),
        (
            '[control]\ndynamics = "unicycle"\n[control.unicycle]\nmax_turn_rad_s = -1.5',
            r"bad\.toml: control\.unicycle\.max_turn_rad_s = -1\.5; .*greater than 0",
        ),
        (
            "[safety]\nbody_diameter_m = 0.6",
            r"bad\.toml: safety\.body_diameter_m = 0\.6; larger than the shape's shortest edge "
            r"\(1–3: 0\.5 m\)",
        ),
        (
            '[network]\ncontrol_default = [{model = "logistic", d50_m = 1.0, width_m = 0.1}]',
            r"bad\.toml: network\.control_default\[0\]\.model = 'logistic'; a distance model on "
            r"a control link needs network\.access_point",
        ),
        (
            "[network]\naccess_point = [0.0, 0.0, 1.0]",
            r"bad\.toml: network\.access_point = \[0\.0, 0\.0, 1\.0\]; expected 2 coordinates",
        ),
        (
            '[runtime]\nmode = "realtime"\n[network]\nformation_default = [{model = "range", max_range_m = 2}]',
            r"network\.formation_default\[0\]\.model = 'range'; a distance model needs runtime\.mode",
        ),
        (
            "[safety.bounds]\nmin_m = [0.0, 0.0]\nmax_m = [1.0, 0.0]",
            r"safety\.bounds\.max_m = \[1\.0, 0\.0\]; expected > min_m = \[0\.0, 0\.0\]",
        ),
    ],
    ids=[
        "range-zero", "range-negative", "width-zero", "speed-zero", "turn-negative",
        "body-too-big", "control-without-ap", "ap-dimension", "realtime", "bounds",
    ],
)  # fmt: skip
def test_bad_input_names_file_field_and_value(tmp_path: Path, text: str, pattern: str) -> None:
    with pytest.raises(ScenarioError, match=pattern):
        load(write(tmp_path, text))


def test_unicycles_move_in_a_plane(tmp_path: Path) -> None:
    flat3d = TRIANGLE.replace("0.0]", "0.0, 0.0]").replace("0.5]", "0.5, 0.0]")
    path = tmp_path / "bad.toml"
    path.write_text(
        "dimension = 3\nallow_flexible = true\n" + flat3d + '[control]\ndynamics = "unicycle"\n'
    )
    with pytest.raises(
        ScenarioError, match=r"control\.dynamics = 'unicycle'; a unicycle moves in a plane"
    ):
        load(path)


def test_initial_headings_are_keyed_and_spread() -> None:
    a = initial_headings(5, 200)
    assert a.tolist() == initial_headings(5, 200).tolist()
    assert a.tolist() != initial_headings(6, 200).tolist()
    assert (a >= -np.pi).all() and (a < np.pi).all() and a.std() > 1.0
