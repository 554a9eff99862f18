"""The plug-in registry: ours and the example package's found the same way, bad ones refused.

The example package (examples/formation-plugins-example) is installed into the test venv
by ``make test``; ``tests/data/plugins`` holds plug-ins that go wrong, named by import path.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from formation.errors import PluginFailure, ScenarioError
from formation.linkmodels import kind_code_of, spec_class
from formation.plugin_api import DYNAMICS, all_strategies, control_law, loss_strategy
from formation.plugin_registry import find, names, registered
from formation.scenario import Scenario, load_dict

ROOT = Path(__file__).resolve().parents[3]
BAD = ROOT / "tests" / "data" / "plugins"
EXAMPLE = ROOT / "examples" / "formation-plugins-example" / "scenario.toml"


@pytest.fixture(autouse=True)
def bad_plugins_importable() -> Iterator[None]:
    sys.path.insert(0, str(BAD))
    yield
    sys.path.remove(str(BAD))


def paper_dict(paper: Scenario, **changes: object) -> dict[str, object]:
    data = paper.model_dump(by_alias=True, exclude_none=True)
    data.update(changes)
    return data


def test_ours_and_the_example_are_registered_the_same_way() -> None:
    assert set(names("strategy")) >= {"zero", "hold", "estimate", "blend", "drop", "extrapolate"}
    assert set(names("controller")) >= {"displacement", "distance", "saturated"}
    assert "jammer" in names("link_model") and "bernoulli" in names("link_model")
    assert registered("strategy")["hold"].package.startswith("formation-testbed ")
    assert registered("strategy")["extrapolate"].package.startswith("formation-plugins-example ")
    assert all_strategies()[:5] == ("zero", "hold", "estimate", "blend", "drop")
    assert "extrapolate" in all_strategies()


def test_a_plugin_is_found_by_import_path_too() -> None:
    assert loss_strategy("formation_example.strategies:EXTRAPOLATE") is loss_strategy("extrapolate")
    assert find("strategy", "bad_plugins:FAILS_LATER").package == "(not packaged)"


def test_our_link_models_keep_their_kind_codes_and_a_plugins_is_stable() -> None:
    assert kind_code_of(spec_class("bernoulli")) == 2  # every seed keeps its numbers
    jammer = kind_code_of(spec_class("jammer"))
    assert jammer >= 64 and jammer == kind_code_of(spec_class("formation_example.jammer:Jammer"))


@pytest.mark.parametrize(
    ("name", "problem"),
    [
        ("nope", r"no loss strategy is registered under this name \(registered: .*blend.*\)"),
        ("broken_import:X", r"cannot import module 'broken_import' \(ModuleNotFoundError: "),
        ("bad_plugins:MISSING", r"module 'bad_plugins' has no attribute 'MISSING'"),
        ("bad_plugins:NOT_A_STRATEGY", r"<object object at 0x[0-9a-f]+> is not a formation.plugin_api.LossStrategy$"),
        ("bad_plugins:WRONG_SIGNATURE", r"fill has the signature \(inputs: 'StrategyInputs'\) -> 'Fill'; expected \(inputs, params\)$"),
        ("bad_plugins:WRONG_SHAPE", r"on a probe of 3 links: Fill.values has the shape \(1, 2\); expected \(3, 2\)"),
    ],
)  # fmt: skip
def test_a_bad_strategy_is_refused_naming_the_file_the_field_and_the_plugin(
    paper: Scenario, name: str, problem: str
) -> None:
    data = paper_dict(paper, strategy={"name": name})
    with pytest.raises(ScenarioError) as err:
        load_dict(data, source="paper.toml")
    assert err.value.field == "strategy.name"
    assert err.match(
        rf"^paper.toml: strategy.name = '{name}'; loss strategy plug-in '{name}': {problem}"
    )


def test_a_strategys_parameters_are_checked_by_its_own_model(paper: Scenario) -> None:
    data = paper_dict(
        paper, strategy={"name": "hold", "params": {"extrapolate": {"horizon_epochs": 0}}}
    )
    with pytest.raises(ScenarioError, match=(
        r"^paper.toml: strategy.params.extrapolate.horizon_epochs = 0; loss strategy plug-in "
        r"'extrapolate': Input should be greater than or equal to 1$"
    )):  # fmt: skip
        load_dict(data, source="paper.toml")
    data = paper_dict(paper, strategy={"name": "hold", "params": {"extrapolate": {"horizon": 3}}})
    with pytest.raises(ScenarioError, match=(
        r"^paper.toml: strategy.params.extrapolate.horizon = 3; loss strategy plug-in "
        r"'extrapolate': unknown parameter$"
    )):  # fmt: skip
        load_dict(data, source="paper.toml")
    data = paper_dict(paper, strategy={"name": "hold", "params": {"nope": {}}})
    with pytest.raises(
        ScenarioError, match=r"strategy.params.nope = 'nope'; loss strategy plug-in 'nope'"
    ):
        load_dict(data, source="paper.toml")


def test_blend_takes_alpha_from_its_table_or_the_sections_older_spelling(paper: Scenario) -> None:
    s = load_dict(paper_dict(paper, strategy={"name": "blend", "alpha": 0.3}))
    assert s.strategy.params_of("blend").alpha == 0.3
    assert s.strategy.sources_of("blend") == {"alpha": "scenario"}
    both = {"name": "blend", "alpha": 0.3, "params": {"blend": {"alpha": 0.9}}}
    assert load_dict(paper_dict(paper, strategy=both)).strategy.params_of("blend").alpha == 0.9
    s = load_dict(paper_dict(paper, strategy={"name": "blend"}))
    assert s.strategy.params_of("blend").alpha == 0.5
    assert s.strategy.sources_of("blend") == {"alpha": "default"}


def test_a_plugin_parameter_named_like_blends_alpha_keeps_its_own_default(
    paper: Scenario,
) -> None:
    name = "bad_plugins:OWN_ALPHA"
    s = load_dict(paper_dict(paper, strategy={"name": name, "alpha": 0.5}))
    assert s.strategy.params_of(name).alpha == 0.9  # not [strategy].alpha, which is blend's
    assert s.strategy.sources_of(name) == {"alpha": "default"}
    s = load_dict(paper_dict(paper, strategy={"name": name, "params": {name: {"alpha": 0.2}}}))
    assert s.strategy.params_of(name).alpha == 0.2
    assert s.strategy.sources_of(name) == {"alpha": "scenario"}


def test_a_link_models_parameter_error_names_the_plugin(paper: Scenario) -> None:
    network = {"formation_default": [{"model": "bernoulli", "p_loss": 1.5}]}
    with pytest.raises(ScenarioError, match=(
        r"^paper.toml: network.formation_default\[0\].p_loss = 1.5; link model plug-in "
        r"'bernoulli': Input should be less than or equal to 1$"
    )):  # fmt: skip
        load_dict(paper_dict(paper, network=network), source="paper.toml")
    network = {"formation_default": [{"model": "bad_plugins:Explodes", "at_epoch": 2}]}
    with pytest.raises(ScenarioError, match=(
        r"^paper.toml: network.formation_default\[0\].at_epoch = 2; link model plug-in "
        r"'bad_plugins:Explodes': Input should be greater than or equal to 8$"
    )):  # fmt: skip
        load_dict(paper_dict(paper, network=network), source="paper.toml")


def test_a_bad_controller_is_refused(paper: Scenario) -> None:
    control = paper.control.model_dump()
    cases = [
        ({**control, "controller": "nope"}, "control.controller", r"no controller is registered"),
        ({**control, "controller": "bad_plugins:SINGLE_ONLY", "dynamics": "double"},
         "control.dynamics", r"controller 'bad_plugins:SINGLE_ONLY' supports only single"),
        ({**control, "controller": "bad_plugins:INFINITE"}, "control.controller",
         r"on a probe of 2 agents: returned a command that is not finite"),
        ({**control, "controller": "saturated", "params": {"saturated": {"max_step_m": -1}}},
         "control.params.saturated.max_step_m",
         r"max_step_m = -1; controller plug-in 'saturated': Input should be greater than 0"),
        ({**control, "params": {"nope": {}}}, "control.params.nope", r"no controller is registered"),
    ]  # fmt: skip
    for section, field, problem in cases:
        with pytest.raises(ScenarioError, match=problem) as err:
            load_dict(paper_dict(paper, control=section), source="paper.toml")
        assert err.value.field == field, err.value


def test_a_bad_link_model_is_refused_naming_its_field(paper: Scenario) -> None:
    jam = {"model": "jammer", "links": [[1, 2]], "length": 5, "every": 2}
    data = paper_dict(paper, network={"formation_default": [jam]})
    with pytest.raises(ScenarioError, match=(
        r"^paper.toml: network.formation_default\[0\] = .*; link model plug-in 'jammer': "
        r"length = 5 is longer than every = 2$"
    )):  # fmt: skip
        load_dict(data, source="paper.toml")
    data = paper_dict(paper, network={"formation_default": [{"model": "jamer"}]})
    with pytest.raises(
        ScenarioError, match=r"link model plug-in 'jamer': no link model is registered"
    ):
        load_dict(data, source="paper.toml")


def test_the_example_scenario_loads_with_its_plugins_and_round_trips() -> None:
    s = Scenario.from_file(EXAMPLE)
    assert (s.strategy.name, s.control.controller) == ("extrapolate", "saturated")
    assert s.strategy.params_of("extrapolate").horizon_epochs == 10
    assert s.control.law_params.max_step_m == 0.15
    again = load_dict(__import__("tomllib").loads(s.to_toml()))
    assert again == s  # the recording's scenario names the plug-ins and their parameters


def test_a_plugin_failing_at_run_time_names_itself_the_agent_and_the_epoch(paper: Scenario) -> None:
    from testbed.sim.simulate import simulate

    lossy = load_dict(paper_dict(
        paper,
        strategy={"name": "bad_plugins:FAILS_LATER", "params": {"bad_plugins:FAILS_LATER": {"at_epoch": 6}}},
    ))  # fmt: skip
    with pytest.raises(PluginFailure, match=(
        r"^loss strategy plug-in 'bad_plugins:FAILS_LATER' failed at epoch 6 \(agents 1, 2\): "
        r"Fill.values is not finite \(NaN or inf\) for a link it fills$"
    )):  # fmt: skip
        simulate(lossy)


def test_the_checked_call_keeps_the_builtins_numbers() -> None:
    """Through the registry, hold gives exactly the last value (no copy, no arithmetic)."""
    from agent import LinkMemory
    from agent.strategies import substitute

    memory = LinkMemory.empty(2, 2)
    memory = LinkMemory(
        np.array([[0.1, 0.2], [0.3, 0.4]]), np.array([0, -1]), memory.state, memory.has_state
    )
    sub, _ = substitute("hold", control_law("displacement").params(), 1, np.array([False, False]),
                        np.zeros((2, 2)), memory, np.zeros((2, 2)), np.zeros(2, bool), np.zeros(2), 1.0,
                        np.array([1, 2]))  # fmt: skip
    np.testing.assert_array_equal(sub.values, [[0.1, 0.2], [0.0, 0.0]])
    assert sub.substituted.tolist() == [True, False]


def test_model_md_describes_every_dynamics_as_implemented() -> None:
    text = (ROOT / "docs" / "model.md").read_text()
    section = text[text.index("\n## 3.") : text.index("\n## 4.")]  # §3, the controller
    assert "not implemented" not in section
    for dynamics in DYNAMICS:  # what a controller may list, each in the text with its code
        assert f"step_{dynamics}" in section, dynamics
