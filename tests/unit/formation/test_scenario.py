"""The scenario file: shipped scenarios load; every kind of bad input names file, field and value."""

from __future__ import annotations

import copy
import math
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from formation.errors import ScenarioError
from formation.scenario import Scenario, load, load_dict
from testbed.sim.team_generators import geometric_team
from testkit.scenario_files import TRIANGLE, scenario_file

SCENARIOS = Path(__file__).resolve().parents[3] / "scenarios"


def write(tmp_path: Path, text: str, name: str = "bad.toml") -> Path:
    return scenario_file(tmp_path, text, name)


@pytest.mark.parametrize("path", sorted(SCENARIOS.glob("*.toml")), ids=lambda p: p.name)
def test_shipped_scenarios_load(path: Path) -> None:
    s = Scenario.from_file(path)
    assert s.n == len(s.agents) and s.edge_array.shape == (len(s.edges), 2)


def test_paper_geometry_is_the_model_md_pentagon(paper: Scenario) -> None:
    angles = np.deg2rad(90 + 72 * np.arange(5))
    np.testing.assert_allclose(paper.offsets, np.c_[np.cos(angles), np.sin(angles)], atol=1e-12)
    assert paper.edge_array.tolist() == [[1, 2], [1, 3], [2, 3], [2, 4], [1, 4], [3, 5], [4, 5]]
    assert paper.control.epsilon == 0.25
    assert paper.formation_link_models(1, 2)[0].model == "outage"
    assert paper.formation_link_models(2, 1)[0].model == "outage"
    assert paper.formation_link_models(2, 3) == ()


def test_weights_are_numpys_norm_of_each_edge_to_the_bit() -> None:
    s = geometric_team(300, 3, 0.5, seed=4)
    d0 = s.offsets
    want = [float(np.linalg.norm(d0[i - 1] - d0[j - 1])) for i, j in s.edge_array]
    assert s.weights.tobytes() == np.array(want).tobytes()
    assert s.edge_array.tolist() == [sorted(e.between) for e in s.edges]


def test_weights_default_to_shape_distances(tmp_path: Path) -> None:
    s = load(write(tmp_path, TRIANGLE))
    np.testing.assert_allclose(s.weights, [1.0, np.hypot(1.0, 0.5), 0.5])  # |1-2|, |2-3|, |1-3|


def test_resolved_toml_round_trips(paper: Scenario, tmp_path: Path) -> None:
    again = load(write(tmp_path, paper.to_toml(), "again.toml"))
    assert again == paper


def test_initial_positions_depend_only_on_seed(paper: Scenario) -> None:
    a, b, c = paper.initial_positions(3), paper.initial_positions(3), paper.initial_positions(4)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)
    np.testing.assert_array_equal(a[0], paper.offsets[0])  # the leader starts on its reference


BAD = [
    ("unknown field", "colour = 3\n" + TRIANGLE, r"bad\.toml: colour = 3; unknown field"),
    (
        "unknown nested field",
        TRIANGLE + "colour = 3\n",
        r"bad\.toml: agents\[2\]\.colour = 3; unknown field",
    ),
    (
        "wrong type",
        TRIANGLE.replace('name = "tri"', 'name = "tri"\nepochs = "many"'),
        r"bad\.toml: epochs = 'many'; .*integer",
    ),
    (
        "negative weight",
        TRIANGLE.replace(
            "edges = [[1, 2], [2, 3], [1, 3]]",
            "edges = [[1, 2], [2, 3], {between = [1, 3], weight = -1.0}]",
        ),
        r"bad\.toml: edges\[2\]\.weight = -1\.0; .*greater than 0",
    ),
    (
        "edge to a missing agent",
        TRIANGLE.replace("[1, 3]]", "[1, 7]]"),
        r"bad\.toml: edges\[2\]\.between = \[1, 7\]; agent 7 does not exist \(agents are 1\.\.3\)",
    ),
    (
        "disconnected graph",
        TRIANGLE.replace(
            "edges = [[1, 2], [2, 3], [1, 3]]", "allow_flexible = true\nedges = [[1, 2]]"
        ),
        r"bad\.toml: edges = \[\[1, 2\]\]; the formation graph is not connected",
    ),
    (
        "non-rigid shape",
        TRIANGLE.replace("edges = [[1, 2], [2, 3], [1, 3]]", "edges = [[1, 2], [2, 3]]"),
        r"bad\.toml: edges = '2 edges'; the shape is not rigid \(rigidity rank 2, need 3\)",
    ),
    (
        "epsilon too large",
        TRIANGLE + "[control]\ngain = 0.6\n",
        r"bad\.toml: control\.gain = 0\.6; epsilon = gain \* period_s = 0\.6 must be < 1/max_degree = 1/2 = 0\.5",
    ),
    ("TOML syntax error", TRIANGLE + "[control\n", r"bad\.toml: TOML syntax error"),
    (
        "bad link model probability",
        TRIANGLE
        + '[[network.links]]\nbetween = [1, 2]\nmodels = [{model = "bernoulli", p_loss = 1.5}]\n',
        r"bad\.toml: network\.links\[0\]\.models\[0\]\.p_loss = 1\.5; .*less than or equal to 1",
    ),
    (
        "link not in the graph",
        TRIANGLE.replace("edges = [[1, 2], [2, 3], [1, 3]]", "edges = [[1, 2], [2, 3], [1, 3]]")
        + "[[network.links]]\nbetween = [1, 4]\n",
        r"network\.links\[0\]\.between = \[1, 4\]; not an edge of the formation graph",
    ),
]


@pytest.mark.parametrize(("case", "text", "pattern"), BAD, ids=[b[0] for b in BAD])
def test_bad_scenarios_name_file_field_and_value(
    tmp_path: Path, case: str, text: str, pattern: str
) -> None:
    with pytest.raises(ScenarioError, match=pattern):
        load(write(tmp_path, text))


def test_an_older_file_with_leader_is_told_the_new_name(tmp_path: Path) -> None:
    old = write(tmp_path, "leader = 1\n" + TRIANGLE, "old.toml")
    with pytest.raises(
        ScenarioError, match=r"^.*old\.toml: leader = 1; this field is now called reference_agent$"
    ):
        load(old)
    assert (
        load(write(tmp_path, "reference_agent = 2\n" + TRIANGLE, "new.toml")).reference_agent == 2
    )


def test_non_rigid_is_accepted_when_allowed(tmp_path: Path) -> None:
    text = TRIANGLE.replace(
        "edges = [[1, 2], [2, 3], [1, 3]]", "allow_flexible = true\nedges = [[1, 2], [2, 3]]"
    )
    assert load(write(tmp_path, text)).allow_flexible


def test_missing_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match=r"nope\.toml: cannot read the file"):
        load(tmp_path / "nope.toml")


def test_load_dict_names_its_source() -> None:
    with pytest.raises(ScenarioError, match=r"^mine: agents = \[\]; "):
        load_dict({"agents": []}, source="mine")


def test_cli_exits_nonzero_with_one_message_and_writes_nothing(tmp_path: Path) -> None:
    bad = write(tmp_path, TRIANGLE + "[control]\ngain = 0.6\n")
    runs = tmp_path / "runs"
    for cmd in (["simulate", str(bad)], ["run", str(bad), "--runs-dir", str(runs)]):
        proc = subprocess.run(
            [sys.executable, "-m", "testbed.cli", *cmd],
            capture_output=True,
            text=True,
            timeout=60,
            cwd=tmp_path,
        )
        assert proc.returncode == 1
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and "bad.toml: control.gain = 0.6" in lines[0], proc.stderr
        assert not runs.exists()


def _plain(data: Any) -> Any:
    """A dumped scenario with its tuples as lists, so that a leaf can be replaced."""
    if isinstance(data, dict):
        return {k: _plain(v) for k, v in data.items()}
    if isinstance(data, (list, tuple)):
        return [_plain(v) for v in data]
    return data


def _float_leaves(data: Any, path: str = "") -> Iterator[tuple[str, list[Any]]]:
    """Every float of a dumped scenario: its field path as the error names it, and its keys."""
    if isinstance(data, dict):
        items: Any = data.items()
    elif isinstance(data, list):
        items = enumerate(data)
    else:
        return
    for key, value in items:
        where = f"{path}[{key}]" if isinstance(key, int) else f"{path}.{key}" if path else key
        if isinstance(value, float):
            yield where, [key]
        for inner, keys in _float_leaves(value, where):
            yield inner, [key, *keys]


@pytest.mark.parametrize("path", sorted(SCENARIOS.glob("*.toml")), ids=lambda p: p.name)
@pytest.mark.parametrize("bad", [math.inf, -math.inf, math.nan], ids=["inf", "-inf", "nan"])
def test_every_float_field_must_be_finite(path: Path, bad: float) -> None:
    # A non-finite number would pass the loader and fail later with numpy warnings.
    dumped = _plain(Scenario.from_file(path).model_dump(by_alias=True))
    leaves = list(_float_leaves(dumped))
    assert len(leaves) >= 10, f"{path.name}: only {len(leaves)} float fields found"
    for where, keys in leaves:
        data = copy.deepcopy(dumped)
        parent = data
        for key in keys[:-1]:
            parent = parent[key]
        parent[keys[-1]] = bad
        pattern = rf"^{path.name}: {re.escape(where)} = {bad!r}; .*finite"
        with pytest.raises(ScenarioError, match=pattern):
            load_dict(data, source=path.name)
