"""The scenario file (TOML) as one frozen pydantic model, loaded once and passed down.

``Scenario.from_file(path)`` reads and validates a file; every problem becomes a
:class:`~formation.errors.ScenarioError` naming the file, the field path and the
value. The model follows docs/model.md: §1 team and shape, §3 control, §4 edge rule,
§5 estimator, §6 strategy, §8 the default experiment (``scenarios/paper.toml``).
"""

from __future__ import annotations

import tomllib
from collections.abc import Callable
from functools import cached_property
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import numpy.typing as npt
import tomli_w
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from formation._error_paths import loc_path, lookup
from formation.body import Body, body_problems
from formation.capacity import Capacity, capacity_problems
from formation.errors import NO_VALUE, ScenarioError
from formation.events import Event, Membership, event_problems, membership
from formation.graph import is_connected, max_degree
from formation.keyed_random import Stream, keyed_normal
from formation.linkmodels import LinkModelSpec
from formation.plugin_api import (
    CHAPTER_STRATEGIES,
    control_law,
    loss_strategy,
    probe_controller,
    probe_strategy,
    validate_params,
)
from formation.plugin_registry import PluginError
from formation.rigidity import SVD_MAX_COLUMNS, expected_rigidity_rank, is_rigid, rigidity_rank
from formation.robots import Safety, Unicycle, robot_problems

StrategyName = str  # a loss strategy plug-in's name (formation.plugin_registry)
# The chapter's strategies, in its order; ``--strategy all`` is every registered one (all_strategies).
STRATEGIES: tuple[str, ...] = CHAPTER_STRATEGIES
LEADER_ENDPOINT = 0  # the leader's end of a control link, in netem's link ids


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class Agent(_Model):
    """One agent: its id and its offset ``d0`` in the shape [m]."""

    id: int = Field(ge=1)
    offset: tuple[float, ...]
    initial: tuple[float, ...] | None = None  # overrides the random initial position


class Edge(_Model):
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


class Initial(_Model):
    """Initial positions: the shape plus N(0, spread_m²) per coordinate, keyed by the seed."""

    spread_m: float = Field(0.3, ge=0.0)


class Controller(_Model):
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
            raise _Problem(
                "control.dynamics",
                self.dynamics,
                f"controller {self.controller!r} supports only {', '.join(law.dynamics)}",
            )
        _params_by_name("control.params", self.params, control_law, self.params_of)
        _plugin(lambda: self.law_params)
        return self

    def params_of(self, name: str) -> Any:
        """Controller ``name``'s parameters, validated by its own model."""
        return validate_params(
            "controller", name, control_law(name).params, self.params.get(name, {})
        )

    @cached_property
    def law_params(self) -> Any:
        """The parameters of the scenario's controller (asked every epoch: validated once)."""
        return self.params_of(self.controller)


class StaticReference(_Model):
    kind: Literal["static"] = "static"


class LineReference(_Model):
    kind: Literal["line"] = "line"
    velocity: tuple[float, ...]  # [m/s]


class CircleReference(_Model):
    kind: Literal["circle"] = "circle"
    radius_m: float = Field(gt=0.0)
    angular_velocity: float  # [rad/s], in the x-y plane


class WaypointReference(_Model):
    kind: Literal["waypoints"] = "waypoints"
    points: tuple[tuple[float, ...], ...] = Field(min_length=1)  # leader positions [m]
    speed_m_s: float = Field(gt=0.0)
    loop: bool = False


Reference = Annotated[
    StaticReference | LineReference | CircleReference | WaypointReference,
    Field(discriminator="kind"),
]


class Noise(_Model):
    """Relative measurement noise ``P_ij``: ``sigma_m² I`` unless a full ``covariance`` is given."""

    sigma_m: float = Field(0.01, ge=0.0)
    covariance: tuple[tuple[float, ...], ...] | None = None


class Strategy(_Model):
    """Loss strategy of docs/model.md §6 and the blend factor α.

    ``name`` names a loss strategy plug-in; ``params`` holds each strategy's parameters by
    its name (``[strategy.params.blend] alpha = 0.3``), so a sweep over every strategy gives
    each its own. A field of this section that a strategy's parameters also have (``alpha``)
    is that parameter's default.
    """

    name: StrategyName = "estimate"
    alpha: float = Field(0.5, gt=0.0, le=1.0)
    params: dict[str, dict[str, Any]] = Field(default_factory=dict)

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
            fields = type(self).model_fields
            shared = {k: getattr(self, k) for k in model.model_fields if k in fields}
            given = {**shared, **self.params.get(name, {})}
            self._validated[name] = validate_params("strategy", name, model, given)
        return self._validated[name]


class Estimator(_Model):
    """Which edges the BLUE uses (§5) and when an edge counts as healthy (§4)."""

    edges: Literal["tree", "healthy"] = "tree"
    edge_rule: Literal["either", "both"] = "either"
    # the leader's covariance blocks on epochs k with k % covariance_every == 0 (seconds at
    # 10,000 agents on an expander); the estimates go out every epoch regardless
    covariance_every: int = Field(1, ge=1)


class FormationLink(_Model):
    """Models on a formation link; ``forward`` is ``between[0] → between[1]``."""

    between: tuple[int, int]
    direction: Literal["both", "forward", "backward"] = "both"
    models: tuple[LinkModelSpec, ...] = ()


class ControlLink(_Model):
    """Models on an agent's control links: ``report`` (agent → leader), ``estimate`` (back)."""

    agent: int
    direction: Literal["both", "report", "estimate"] = "both"
    models: tuple[LinkModelSpec, ...] = ()


class Network(_Model):
    formation_default: tuple[LinkModelSpec, ...] = ()
    control_default: tuple[LinkModelSpec, ...] = ()
    links: tuple[FormationLink, ...] = ()
    control: tuple[ControlLink, ...] = ()
    access_point: tuple[float, ...] | None = None  # [m] control links' radio end (distance models)
    capacity: tuple[Capacity, ...] = ()  # rate-limited queues (formation.capacity)


class Runtime(_Model):
    mode: Literal["lockstep", "realtime"] = "lockstep"
    realtime_period_s: float | None = Field(None, gt=0.0)  # wall-clock period; default period_s


class RecordingSettings(_Model):
    compression: Literal["zstd", "lz4", "none"] = "zstd"


class Scenario(_Model):
    """A whole scenario. Agents are ids ``1..n``; row ``i − 1`` of every array is agent ``i``."""

    name: str = "unnamed"
    description: str = ""
    seed: int = Field(0, ge=0)
    epochs: int = Field(50, ge=1)
    dimension: Literal[2, 3] = 2
    leader: int = 1
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

    # -- checks that need the whole scenario ------------------------------------------------
    @model_validator(mode="after")
    def _check(self) -> Scenario:
        for problem in _problems(self):
            raise _Problem(*problem)
        return self

    # -- derived arrays (computed once; the model is frozen) --------------------------------
    @property
    def n(self) -> int:
        return len(self.agents)

    @cached_property
    def membership(self) -> Membership:
        """Who takes part at each epoch, from ``events`` (:class:`formation.events.Membership`)."""
        return membership(self.n, self.epochs, self.events)

    @cached_property
    def offsets(self) -> npt.NDArray[np.float64]:
        """Shape offsets ``d0``: (n, d) array [m]."""
        return np.array([a.offset for a in self.agents], dtype=float)

    @cached_property
    def edge_array(self) -> npt.NDArray[np.int64]:
        """Formation edges as an (m, 2) array of agent ids, smaller id first."""
        return np.array([sorted(e.between) for e in self.edges], dtype=np.int64).reshape(-1, 2)

    @cached_property
    def weights(self) -> npt.NDArray[np.float64]:
        """Edge weights ``w_ij`` (the desired distances ``C_ij`` unless given): (m,) [m]."""
        d0 = self.offsets
        out = []
        for e, (i, j) in zip(self.edges, self.edge_array, strict=True):
            out.append(
                e.weight if e.weight is not None else float(np.linalg.norm(d0[i - 1] - d0[j - 1]))
            )
        return np.array(out, dtype=float)

    @cached_property
    def noise_covariance(self) -> npt.NDArray[np.float64]:
        """``P_ij`` for every edge and epoch: (d, d) [m²]."""
        if self.noise.covariance is not None:
            return np.array(self.noise.covariance, dtype=float)
        return self.noise.sigma_m**2 * np.eye(self.dimension)

    def initial_positions(self, seed: int | None = None) -> npt.NDArray[np.float64]:
        """``x[0]``: shape + N(0, spread²) keyed by ``(seed, INITIAL, i, coord)``; the leader on its reference."""
        seed = self.seed if seed is None else seed
        ids = np.arange(1, self.n + 1)[:, None]
        coords = np.arange(self.dimension)[None, :]
        x0 = self.offsets + self.initial.spread_m * keyed_normal(seed, Stream.INITIAL, ids, coords)
        for a in self.agents:
            if a.initial is not None:
                x0[a.id - 1] = a.initial
        x0[self.leader - 1] = self.offsets[self.leader - 1]
        return x0

    def formation_link_models(self, src: int, dst: int) -> tuple[LinkModelSpec, ...]:
        """The model stack on formation link ``src → dst``.

        Entries of ``network.links`` naming the link replace the default stack; several
        entries naming the same direction stack in file order.
        """
        stack: list[LinkModelSpec] = []
        named = False
        for link in self.network.links:
            a, b = link.between
            forward = (a, b) == (src, dst)
            backward = (b, a) == (src, dst)
            if (forward and link.direction in ("both", "forward")) or (
                backward and link.direction in ("both", "backward")
            ):
                stack.extend(link.models)
                named = True
        return tuple(stack) if named else self.network.formation_default

    def control_link_models(
        self, agent: int, direction: Literal["report", "estimate"]
    ) -> tuple[LinkModelSpec, ...]:
        """The model stack on agent ``agent``'s control link (``report``: to the leader; ``estimate``: back)."""
        stack: list[LinkModelSpec] = []
        named = False
        for link in self.network.control:
            if link.agent == agent and link.direction in ("both", direction):
                stack.extend(link.models)
                named = True
        return tuple(stack) if named else self.network.control_default

    @cached_property
    def directed_links(self) -> npt.NDArray[np.int64]:
        """Formation links as (L, 2) ``(src, dst)``: for edge ``e`` row ``2e`` is ``i → j``, ``2e + 1`` is ``j → i``."""
        e = self.edge_array
        return np.stack([e, e[:, ::-1]], axis=1).reshape(-1, 2)

    @cached_property
    def in_neighbours(self) -> list[list[int]]:
        """Per agent ``i`` (row ``i − 1``), the ids ``j`` of its in-links ``j → i``, ascending."""
        senders: list[list[int]] = [[] for _ in range(self.n)]
        for j, i in self.directed_links.tolist():
            senders[i - 1].append(j)
        return [sorted(s) for s in senders]

    def model_stacks(self) -> list[tuple[str, tuple[LinkModelSpec, ...]]]:
        """Every stack of link models the scenario writes, as ``(field, models)``."""
        formation, control = _stacks(self)
        return [(field, tuple(models)) for field, models in (*formation, *control)]

    def with_strategy(self, name: str) -> Scenario:
        """A validated copy that runs loss strategy ``name`` (its parameters kept)."""
        return self.with_overrides(strategy={**self.strategy.model_dump(), "name": name})

    def with_overrides(self, **changes: Any) -> Scenario:
        """A validated copy with top-level fields replaced (e.g. ``seed``, ``epochs``, ``strategy``)."""
        data = self.model_dump(by_alias=True)
        for key, value in changes.items():
            data[key] = value.model_dump(by_alias=True) if isinstance(value, BaseModel) else value
        return load_dict(data, source=f"{self.name} (overridden)")

    def to_toml(self) -> str:
        """The resolved scenario as TOML, stored with every run."""
        return tomli_w.dumps(self.model_dump(by_alias=True, exclude_none=True))

    @classmethod
    def from_file(cls, path: str | Path) -> Scenario:
        return load(path)


def _plugin(check: Any, field: str | None = None, value: object = None) -> Any:
    """``check()``, a plug-in's lookup or validation; its :class:`PluginError` becomes the
    scenario's error (at ``field`` when given, else at the field being validated)."""
    try:
        return check()
    except PluginError as exc:
        if field is None:
            raise ValueError(str(exc)) from None
        raise _Problem(field, value, str(exc)) from None


def _params_by_name(
    field: str, params: dict[str, Any], find: Callable[[str], Any], params_of: Callable[[str], Any]
) -> None:
    """Each name of ``params`` (``{plug-in: its parameters}``) is a plug-in, and its own model
    takes its parameters; a problem is the scenario's at ``field.<name>``."""
    for name, given in params.items():
        _plugin(lambda name=name: find(name), f"{field}.{name}", name)
        _plugin(lambda name=name: params_of(name), f"{field}.{name}", given)


class _Problem(ValueError):
    """A whole-scenario problem, carried through pydantic to :func:`load_dict`."""

    def __init__(self, field: str, value: object, problem: str) -> None:
        self.field, self.value, self.problem = field, value, problem
        super().__init__(f"{field} = {value!r}; {problem}")


def _problems(s: Scenario) -> list[tuple[str, object, str]]:
    d, n = s.dimension, len(s.agents)
    ids = [a.id for a in s.agents]
    if sorted(ids) != list(range(1, n + 1)):
        return [("agents", ids, f"agent ids must be 1..{n} without gaps or repeats")]
    if ids != sorted(ids):
        return [("agents", ids, "list the agents in id order")]
    by_id = {a.id: k for k, a in enumerate(s.agents)}
    for k, a in enumerate(s.agents):
        if len(a.offset) != d:
            return [(f"agents[{k}].offset", list(a.offset), f"expected {d} coordinates")]
        if a.initial is not None and len(a.initial) != d:
            return [(f"agents[{k}].initial", list(a.initial), f"expected {d} coordinates")]
    if s.leader not in by_id:
        return [("leader", s.leader, f"no agent has this id (agents are 1..{n})")]
    seen: set[tuple[int, int]] = set()
    for k, e in enumerate(s.edges):
        for i in e.between:
            if i not in by_id:
                return [
                    (
                        f"edges[{k}].between",
                        list(e.between),
                        f"agent {i} does not exist (agents are 1..{n})",
                    )
                ]
        key = (min(e.between), max(e.between))
        if key in seen:
            return [(f"edges[{k}].between", list(e.between), "edge listed twice")]
        seen.add(key)
    d0 = np.array([a.offset for a in s.agents], dtype=float)
    pairs = np.array([sorted(e.between) for e in s.edges], dtype=np.int64).reshape(-1, 2)
    for k, (i, j) in enumerate(pairs):
        if np.linalg.norm(d0[i - 1] - d0[j - 1]) == 0.0:
            return [
                (f"edges[{k}].between", [int(i), int(j)], "the two agents have the same offset")
            ]
    if n > 1 and not is_connected(n, pairs):
        return [
            ("edges", [list(map(int, p)) for p in pairs], "the formation graph is not connected")
        ]
    if n > 1 and not s.allow_flexible:
        need = expected_rigidity_rank(n, d)
        if not is_rigid(d0, pairs):
            have = (
                f"rigidity rank {rigidity_rank(d0, pairs)}"
                if n * d <= SVD_MAX_COLUMNS
                else "not rigid"
            )
            return [
                (
                    "edges",
                    f"{len(pairs)} edges",
                    f"the shape is not rigid ({have}, need {need}); "
                    "add edges or set allow_flexible = true",
                )
            ]
    delta = max_degree(n, pairs) if n > 1 else 0
    eps = s.control.epsilon
    if delta > 0 and eps >= 1.0 / delta:
        return [
            (
                "control.gain",
                s.control.gain,
                f"epsilon = gain * period_s = {eps:g} must be < 1/max_degree = 1/{delta} = {1.0 / delta:g}",
            )
        ]
    ref = s.reference
    if isinstance(ref, LineReference) and len(ref.velocity) != d:
        return [("reference.velocity", list(ref.velocity), f"expected {d} coordinates")]
    if isinstance(ref, WaypointReference):
        for k, p in enumerate(ref.points):
            if len(p) != d:
                return [(f"reference.points[{k}]", list(p), f"expected {d} coordinates")]
    if s.noise.covariance is not None:
        cov = np.array(s.noise.covariance, dtype=float)
        if cov.shape != (d, d):
            return [("noise.covariance", s.noise.covariance, f"expected a {d}x{d} matrix")]
        if not np.allclose(cov, cov.T) or np.min(np.linalg.eigvalsh(cov)) <= 0.0:
            return [
                (
                    "noise.covariance",
                    s.noise.covariance,
                    "expected a symmetric positive definite matrix",
                )
            ]
    edge_set = {(int(i), int(j)) for i, j in pairs}
    for k, link in enumerate(s.network.links):
        key = (min(link.between), max(link.between))
        if key not in edge_set:
            return [
                (
                    f"network.links[{k}].between",
                    list(link.between),
                    "not an edge of the formation graph",
                )
            ]
    for k, c in enumerate(s.network.control):
        if c.agent not in by_id:
            return [
                (
                    f"network.control[{k}].agent",
                    c.agent,
                    f"agent does not exist (agents are 1..{n})",
                )
            ]
    # both ways of each edge, from ``pairs``: a cached property set here would break ``==``
    directed = [(int(i), int(j)) for a, b in pairs for i, j in ((a, b), (b, a))]
    capacity = capacity_problems(s.network.capacity, n, directed)
    if capacity:
        return capacity
    events = event_problems(n, s.leader, s.epochs, pairs, s.events, s.allow_split)
    if events:
        return events
    body = body_problems(s.body, n, len(s.events), s.runtime.mode)
    if body:
        return body
    probed = _probe_plugins(s)
    if probed:
        return probed
    return robot_problems(
        s.dimension,
        s.control.dynamics,
        s.runtime.mode,
        s.safety,
        s.network.access_point,
        _edge_lengths(s, d0, pairs),
        *_stacks(s),
    )


def _probe_plugins(s: Scenario) -> list[tuple[str, object, str]]:
    """Call the scenario's strategy and controller once on a small input (docs/plugins.md)."""
    strategy, control = s.strategy, s.control
    try:
        _probed("strategy", strategy.name, strategy.params_of(strategy.name), s.dimension, "")
    except PluginError as exc:
        return [("strategy.name", strategy.name, str(exc))]
    try:
        _probed("controller", control.controller, control.law_params, s.dimension, control.dynamics)
    except PluginError as exc:
        return [("control.controller", control.controller, str(exc))]
    return []


_PROBED: set[tuple[str, str, str, int, str]] = set()  # a with_overrides per sweep cell probes once


def _probed(kind: str, name: str, params: BaseModel, dimension: int, dynamics: str) -> None:
    key = (kind, name, params.model_dump_json(), dimension, dynamics)
    if key in _PROBED:
        return
    if kind == "strategy":
        probe_strategy(name, params, dimension)
    else:
        probe_controller(name, params, dimension, dynamics)
    _PROBED.add(key)


def _edge_lengths(
    s: Scenario, d0: npt.NDArray[np.float64], pairs: npt.NDArray[np.int64]
) -> list[tuple[str, float]]:
    return [(f"{i}–{j}", float(np.linalg.norm(d0[i - 1] - d0[j - 1]))) for i, j in pairs.tolist()]


def _stacks(s: Scenario) -> tuple[list[tuple[str, Any]], list[tuple[str, Any]]]:
    """The formation and control link stacks as ``(field, models)``."""
    net = s.network
    formation = [("network.formation_default", net.formation_default)]
    formation += [(f"network.links[{k}].models", link.models) for k, link in enumerate(net.links)]
    control = [("network.control_default", net.control_default)]
    control += [(f"network.control[{k}].models", c.models) for k, c in enumerate(net.control)]
    return formation, control


def load_dict(data: dict[str, Any], source: str = "<scenario>") -> Scenario:
    """Validate a scenario given as a dict; errors name ``source``, the field path and the value."""
    try:
        return Scenario.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        ctx = err.get("ctx") or {}
        inner = ctx.get("error")
        if isinstance(inner, _Problem):
            raise ScenarioError(source, inner.field, inner.value, inner.problem) from None
        loc = err["loc"]
        value = err.get("input", NO_VALUE) if err["type"] != "missing" else NO_VALUE
        if err["type"] == "extra_forbidden":
            problem = "unknown field"
        elif err["type"] == "missing":
            problem = "required field is missing"
        else:
            problem = err["msg"].removeprefix("Value error, ")
        if value is NO_VALUE and err["type"] != "missing":
            value = lookup(Scenario, data, loc)
        raise ScenarioError(source, loc_path(Scenario, loc), value, problem) from None


def load(path: str | Path) -> Scenario:
    """Read a scenario TOML file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ScenarioError(
            str(path), "", NO_VALUE, f"cannot read the file ({exc.strerror})"
        ) from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(str(path), "", NO_VALUE, f"TOML syntax error: {exc}") from None
    return load_dict(data, source=str(path))
