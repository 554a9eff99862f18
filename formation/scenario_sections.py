"""The sections of a scenario file, each a frozen pydantic model (docs/model.md §1, §3–§6).

:class:`formation.scenario.Scenario` holds one of each; a problem a section finds with
another section's value is raised as :class:`FieldProblem`, which
:func:`formation.scenario.load_dict` turns into the file's :class:`~formation.errors.ScenarioError`.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import cached_property
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from formation.air import Air
from formation.body import Body
from formation.capacity import Capacity
from formation.errors import PLUGIN_LABELS, PluginError, PluginParameterError
from formation.events import Event
from formation.linkmodels import LinkModelSpec
from formation.plugin_api import (
    ParamSource,
    control_law,
    loss_strategy,
    param_sources,
    validate_params,
)
from formation.robots import Safety, Unicycle

StrategyName = str  # a loss strategy plug-in's name (formation.plugin_registry)


class StrictModel(BaseModel):
    """A scenario model: unknown fields, changes after loading and inf/nan are refused."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class Agent(StrictModel):
    """One agent: its id and its offset ``d0`` in the shape [m]."""

    id: int = Field(ge=1)
    offset: tuple[float, ...]
    initial: tuple[float, ...] | None = None  # overrides the random initial position


class Edge(StrictModel):
    """An undirected formation edge; ``weight`` defaults to the shape's distance ``C_ij``."""

    between: tuple[int, int]
    weight: float | None = Field(None, gt=0.0)

    @model_validator(mode="before")
    @classmethod
    def _from_pair(cls, data: Any) -> Any:
        if isinstance(data, list | tuple):
            return {"between": data}
        return data

    @field_validator("between")
    @classmethod
    def _distinct(cls, v: tuple[int, int]) -> tuple[int, int]:
        if v[0] == v[1]:
            raise ValueError(f"an edge joins two different agents, got {list(v)}")
        return v


class Initial(StrictModel):
    """Initial positions: the shape plus N(0, spread_m²) per coordinate, keyed by the seed."""

    spread_m: float = Field(0.3, ge=0.0)


class Controller(StrictModel):
    """The formation controller (docs/model.md §3); ``epsilon = gain * period_s``.

    ``controller`` names a controller plug-in (``displacement``, ``distance`` or a user's);
    ``params`` holds each controller's parameters by its name (``[control.params.saturated]``),
    checked by the plug-in's own model, so a study over controllers gives each its own.
    """

    controller: str = "displacement"
    dynamics: Literal["single", "double", "unicycle"] = "single"
    gain: float = Field(0.25, gt=0.0)  # k [1/s]
    period_s: float = Field(1.0, gt=0.0)  # T [s]
    damping: float = Field(1.0, gt=0.0)  # c [1/s], double integrator only
    unicycle: Unicycle = Unicycle()  # limits and look-ahead, dynamics = "unicycle" only
    params: dict[str, dict[str, Any]] = Field(default_factory=dict)

    @property
    def epsilon(self) -> float:
        return self.gain * self.period_s

    @field_validator("controller")
    @classmethod
    def _registered(cls, name: str) -> str:
        _plugin(lambda: control_law(name))
        return name

    @model_validator(mode="after")
    def _plugin_fits(self) -> Controller:
        law = control_law(self.controller)
        if self.dynamics not in law.dynamics:
            raise FieldProblem(
                "control.dynamics",
                self.dynamics,
                f"controller {self.controller!r} supports only {', '.join(law.dynamics)}",
            )
        _params_by_name("control.params", self.params, control_law, self.params_of)
        _plugin(lambda: self.law_params)
        return self

    def sources_of(self, name: str) -> dict[str, ParamSource]:
        """Where each of controller ``name``'s parameters comes from."""
        return param_sources(control_law(name).params, self.params.get(name, {}))

    def params_of(self, name: str) -> Any:
        """Controller ``name``'s parameters, validated by its own model."""
        return validate_params(
            "controller", name, control_law(name).params, self.params.get(name, {})
        )

    @cached_property
    def law_params(self) -> Any:
        """The parameters of the scenario's controller (asked every epoch: validated once)."""
        return self.params_of(self.controller)


class StaticReference(StrictModel):
    kind: Literal["static"] = "static"


class LineReference(StrictModel):
    kind: Literal["line"] = "line"
    velocity: tuple[float, ...]  # [m/s]


class CircleReference(StrictModel):
    kind: Literal["circle"] = "circle"
    radius_m: float = Field(gt=0.0)
    angular_velocity: float  # [rad/s], in the x-y plane


class WaypointReference(StrictModel):
    kind: Literal["waypoints"] = "waypoints"
    points: tuple[tuple[float, ...], ...] = Field(min_length=1)  # leader positions [m]
    speed_m_s: float = Field(gt=0.0)
    loop: bool = False


Reference = Annotated[
    StaticReference | LineReference | CircleReference | WaypointReference,
    Field(discriminator="kind"),
]


class Noise(StrictModel):
    """Relative measurement noise ``P_ij``: ``sigma_m² I`` unless a full ``covariance`` is given."""

    sigma_m: float = Field(0.01, ge=0.0)
    covariance: tuple[tuple[float, ...], ...] | None = None


class Strategy(StrictModel):
    """Loss strategy of docs/model.md §6.

    ``name`` names a loss strategy plug-in; ``params`` holds each strategy's parameters by
    its name (``[strategy.params.blend] alpha = 0.3``), so a sweep over every strategy gives
    each its own. A plug-in's parameters come from its own table or its own defaults, never
    from another field of this section. ``alpha`` directly under ``[strategy]`` is the older
    spelling of ``[strategy.params.blend] alpha``, read as that (the table's wins).
    """

    name: StrategyName = "estimate"
    params: dict[str, dict[str, Any]] = Field(default_factory=dict)

    @model_validator(mode="before")
    @classmethod
    def _blend_alpha_in_its_table(cls, data: Any) -> Any:
        """``[strategy] alpha``: blend's, unless ``[strategy.params.blend]`` sets it."""
        if not isinstance(data, dict) or "alpha" not in data:
            return data
        params = data.get("params") or {}
        blend = params.get("blend") or {} if isinstance(params, dict) else None
        if not isinstance(blend, dict):
            return data  # the wrong type: pydantic says so at its field
        rest = {k: v for k, v in data.items() if k != "alpha"}
        return {**rest, "params": {**params, "blend": {"alpha": data["alpha"], **blend}}}

    @field_validator("name")
    @classmethod
    def _registered(cls, name: str) -> str:
        _plugin(lambda: loss_strategy(name))
        return name

    @model_validator(mode="after")
    def _params_fit(self) -> Strategy:
        _params_by_name("strategy.params", self.params, loss_strategy, self.params_of)
        _plugin(lambda: self.params_of(self.name))
        return self

    @cached_property
    def _validated(self) -> dict[str, Any]:
        """Each strategy's validated parameters, by name (a plain dict: read every epoch)."""
        return {}

    def params_of(self, name: str) -> Any:
        """Strategy ``name``'s parameters, validated by its own model."""
        if name not in self._validated:  # asked every epoch: validated once
            model = loss_strategy(name).params
            given = self.params.get(name, {})
            self._validated[name] = validate_params("strategy", name, model, given)
        return self._validated[name]

    def sources_of(self, name: str) -> dict[str, ParamSource]:
        """Where each of strategy ``name``'s parameters comes from."""
        return param_sources(loss_strategy(name).params, self.params.get(name, {}))


class Estimator(StrictModel):
    """Which edges the BLUE uses (§5) and when an edge counts as healthy (§4)."""

    edges: Literal["tree", "healthy"] = "tree"
    edge_rule: Literal["either", "both"] = "either"
    # the leader's covariance blocks on epochs k with k % covariance_every == 0 (seconds at
    # 10,000 agents on an expander); the estimates go out every epoch regardless
    covariance_every: int = Field(1, ge=1)


class FormationLink(StrictModel):
    """Models on a formation link; ``forward`` is ``between[0] → between[1]``."""

    between: tuple[int, int]
    direction: Literal["both", "forward", "backward"] = "both"
    models: tuple[LinkModelSpec, ...] = ()


class ControlLink(StrictModel):
    """Models on an agent's control links: ``report`` (agent → leader), ``estimate`` (back)."""

    agent: int
    direction: Literal["both", "report", "estimate"] = "both"
    models: tuple[LinkModelSpec, ...] = ()


class Network(StrictModel):
    formation_default: tuple[LinkModelSpec, ...] = ()
    control_default: tuple[LinkModelSpec, ...] = ()
    links: tuple[FormationLink, ...] = ()
    control: tuple[ControlLink, ...] = ()
    access_point: tuple[float, ...] | None = None  # [m] control links' radio end (distance models)
    capacity: tuple[Capacity, ...] = ()  # rate-limited queues (formation.capacity)
    air: Air | None = None  # a shared 802.11 channel (formation.air)


class Runtime(StrictModel):
    mode: Literal["lockstep", "realtime"] = "lockstep"
    realtime_period_s: float | None = Field(None, gt=0.0)  # wall-clock period; default period_s


class RecordingSettings(StrictModel):
    compression: Literal["zstd", "lz4", "none"] = "zstd"


class ScenarioFields(StrictModel):
    """A scenario's fields, each section checked alone; :class:`formation.scenario.Scenario`
    adds the checks of the whole (:mod:`formation.scenario_checks`) and what follows from it."""

    name: str = "unnamed"
    description: str = ""
    seed: int = Field(0, ge=0)
    epochs: int = Field(50, ge=1)
    dimension: Literal[2, 3] = 2
    reference_agent: int = 1  # the agent that knows its position: the estimates' reference
    allow_flexible: bool = False
    allow_split: bool = False  # events may split the team taking part
    agents: tuple[Agent, ...] = Field(min_length=1)
    edges: tuple[Edge, ...] = ()
    initial: Initial = Initial()
    control: Controller = Field(default_factory=Controller)  # lazily: it loads a plug-in
    reference: Reference = StaticReference()
    noise: Noise = Noise()
    strategy: Strategy = Field(default_factory=Strategy)  # lazily: it loads a plug-in
    estimator: Estimator = Estimator()
    network: Network = Network()
    runtime: Runtime = Runtime()
    recording: RecordingSettings = RecordingSettings()
    body: Body = Body()  # where the agents' bodies are (formation.body)
    safety: Safety = Safety()
    events: tuple[Event, ...] = ()  # leave, join, crash, restart (formation.events)


def _plugin(check: Any, field: str | None = None, value: object = None) -> Any:
    """``check()``, a plug-in's lookup or validation; its :class:`PluginError` becomes the
    scenario's error (at ``field`` when given, else at the field being validated)."""
    try:
        return check()
    except PluginError as exc:
        if field is None:
            raise ValueError(str(exc)) from None
        raise FieldProblem(field, value, str(exc)) from None


def _params_by_name(
    field: str, params: dict[str, Any], find: Callable[[str], Any], params_of: Callable[[str], Any]
) -> None:
    """Each name of ``params`` (``{plug-in: its parameters}``) is a plug-in, and its own model
    takes its parameters; a problem is the scenario's at ``field.<name>``."""
    for name, given in params.items():
        _plugin(lambda name=name: find(name), f"{field}.{name}", name)
        try:
            params_of(name)
        except PluginParameterError as exc:
            at = f"{field}.{name}" + (f".{exc.param}" if exc.param else "")
            label = f"{PLUGIN_LABELS[exc.kind]} plug-in {name!r}"
            raise FieldProblem(at, exc.value, f"{label}: {exc.rule}") from None
        except PluginError as exc:
            raise FieldProblem(f"{field}.{name}", given, str(exc)) from None


class FieldProblem(ValueError):
    """A problem at a field of the scenario, carried through pydantic to
    :func:`formation.scenario.load_dict`, which raises it as the file's ``ScenarioError``."""

    def __init__(self, field: str, value: object, problem: str) -> None:
        self.field, self.value, self.problem = field, value, problem
        super().__init__(f"{field} = {value!r}; {problem}")
