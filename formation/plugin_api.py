"""What a loss strategy and a controller plug-in are, and how each is called and checked.

A plug-in is a small frozen object: a vectorised function over arrays, the pydantic model
of its parameters, and what it needs (a strategy's per-link state, a controller's
dynamics). The built-ins (``agent.strategies``, ``agent.control``) are objects of these
same classes, registered by entry point like a user's (``formation.plugin_registry``).
Link model plug-ins are specs (``formation.linkmodels.Spec``) with a netem layer.

Every call goes through :func:`fill_checked` / :func:`command_checked`: an exception, a
wrong shape or a value that is not finite becomes a :class:`PluginFailure` naming the
plug-in, the agents and the epoch. :func:`probe_strategy` and :func:`probe_controller`
make that call once on a small made-up input when a scenario loads (docs/plugins.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from typing import Any, Literal, NamedTuple

import numpy as np
import numpy.typing as npt
from pydantic import BaseModel, ConfigDict, ValidationError

from formation.errors import PluginError, PluginFailure, PluginKind, PluginParameterError
from formation.plugin_registry import (
    CHAPTER_STRATEGIES,
    all_strategies,
    check_callable,
    load,
)

Array = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]
Ints = npt.NDArray[np.int64]

DYNAMICS = ("single", "double", "unicycle")
PLUGIN_EXIT = 3  # a service's exit code when a plug-in failed: the launcher ends the run
PLUGIN_FAILED = "plug-in failed: "  # how its last status's detail starts (the report reads it)


class NoParams(BaseModel):
    """The parameters of a plug-in that takes none."""

    model_config = ConfigDict(extra="forbid", frozen=True)


# ----------------------------------------------------------------------------- loss strategies


class StrategyInputs(NamedTuple):
    """What a loss strategy knows of ``L`` in-links ``j → i`` at epoch ``k`` (docs/model.md §6).

    Attributes
    ----------
    epoch : the epoch ``k``
    arrived : (L,) bool, the link's epoch-``k`` packet arrived in time
    received : (L, d) its ``x_j[k]`` where arrived (zeros elsewhere) [m]
    last : (L, d) the last ``x_j`` received before epoch ``k`` [m]
    last_epoch : (L,) int, the epoch ``last`` was sent at (−1: nothing received yet)
    estimate : (L, d) the leader's ``x̂_j[k]`` [m], where ``has_estimate`` (L,) bool
    v_ref_prev : (L, d) ``v_ref[k − 1]`` as each receiver knows it [m/s] (zeros at k = 0)
    period_s : the epoch's period ``T`` [s]
    state : (L, w) the strategy's own per-link state from epoch ``k − 1`` (``w`` its width)
    has_state : (L,) bool, where ``state`` was ever set (False after a restart)
    lost : (L,) bool, ``~arrived``; has_last : (L,) bool, ``last_epoch >= 0`` (each computed once)
    """

    epoch: int
    arrived: Mask
    received: Array
    last: Array
    last_epoch: Ints
    estimate: Array
    has_estimate: Mask
    v_ref_prev: Array
    period_s: float
    state: Array
    has_state: Mask
    lost: Mask
    has_last: Mask


class Fill(NamedTuple):
    """A strategy's answer for ``L`` in-links.

    Attributes
    ----------
    values : (L, d) ``x̃_j[k]`` for the lost links it fills [m] (other rows are ignored)
    have : (L,) bool, lost links given a value: their term enters the consensus sum
    fallback : (L,) bool, links where the strategy fell back (counted in the run's summary)
    state : (L, w) its per-link state for epoch ``k + 1``
    has_state : (L,) bool
    """

    values: Array
    have: Mask
    fallback: Mask
    state: Array
    has_state: Mask


def _no_state(dimension: int) -> int:
    return 0


@dataclass(frozen=True)
class LossStrategy:
    """A loss strategy plug-in.

    ``fill(inputs, params) -> Fill`` is called once per epoch for every in-link of an agent,
    a pool or a whole batch of runs at once; ``params`` is an instance of ``params``.
    ``state_width(d)`` is how many floats of state it keeps per link (0: none).
    """

    fill: Callable[[StrategyInputs, Any], Fill]
    params: type[BaseModel] = NoParams
    state_width: Callable[[int], int] = _no_state
    description: str = ""


# ----------------------------------------------------------------------------- controllers


class ControlInputs(NamedTuple):
    """What a controller knows of ``n`` agents and their ``L`` in-links (docs/model.md §3).

    Attributes
    ----------
    n : agents in the batch (rows of the command)
    receivers : (L,) int, the row of each link's receiver ``i``
    relative : (L, d) ``z̃_ij``: measured where the packet arrived, from the substitute elsewhere [m]
    desired : (L, d) ``d0_i − d0_j`` [m]
    distance_sq : (L,) ``C_ij²`` [m²]
    used : (L,) bool, the link's term enters the sum (False: ``drop``, or nothing to fill with)
    epsilon : ``ε = k T``
    period_s : ``T`` [s]
    positions : (n, d) ``x_i[k]`` [m]; velocities (n, d) [m/s] (double integrator; zeros else)
    dynamics : ``single``, ``double`` or ``unicycle``
    epoch : the epoch ``k``; time_s : its time ``k T`` [s] (for a law that varies in time)
    """

    n: int
    receivers: Ints
    relative: Array
    desired: Array
    distance_sq: Array
    used: Mask
    epsilon: float
    period_s: float
    positions: Array
    velocities: Array
    dynamics: str
    epoch: int
    time_s: float


@dataclass(frozen=True)
class ControlLaw:
    """A controller plug-in: ``command(inputs, params) -> (n, d)`` position increment [m].

    The increment is what the single integrator adds in one epoch; the double integrator
    takes it as ``command / T²`` of acceleration, the unicycle as the look-ahead point's
    velocity ``command / T`` (``agent.control``). ``dynamics`` lists those it supports.
    """

    command: Callable[[ControlInputs, Any], Array]
    params: type[BaseModel] = NoParams
    dynamics: tuple[str, ...] = DYNAMICS
    description: str = ""


# ----------------------------------------------------------------------------- finding one


@cache
def loss_strategy(name: str) -> LossStrategy:
    """The loss strategy plug-in ``name`` (registered, or ``"package.module:name"``)."""
    obj = load("strategy", name)
    if not isinstance(obj, LossStrategy):
        raise PluginError("strategy", name, f"{obj!r} is not a formation.plugin_api.LossStrategy")
    check_callable("strategy", name, "fill", obj.fill, ("inputs", "params"))
    check_callable("strategy", name, "state_width", obj.state_width, ("dimension",))
    _check_params("strategy", name, obj.params)
    return obj


@cache
def control_law(name: str) -> ControlLaw:
    """The controller plug-in ``name`` (registered, or ``"package.module:name"``)."""
    obj = load("controller", name)
    if not isinstance(obj, ControlLaw):
        raise PluginError("controller", name, f"{obj!r} is not a formation.plugin_api.ControlLaw")
    check_callable("controller", name, "command", obj.command, ("inputs", "params"))
    _check_params("controller", name, obj.params)
    unknown = sorted(set(obj.dynamics) - set(DYNAMICS))
    if not obj.dynamics or unknown:
        raise PluginError(
            "controller", name, f"dynamics = {obj.dynamics!r}; expected some of {DYNAMICS}"
        )
    return obj


def _check_params(kind: PluginKind, name: str, params: object) -> None:
    if not (isinstance(params, type) and issubclass(params, BaseModel)):
        raise PluginError(kind, name, f"params = {params!r} is not a pydantic model class")


def validate_params(
    kind: PluginKind, name: str, model: type[BaseModel], given: dict[str, Any]
) -> Any:
    """``given`` as ``model``; a failure names the parameter, its value and the rule."""
    try:
        return model.model_validate(given)
    except ValidationError as exc:
        err = exc.errors()[0]
        param = ".".join(str(p) for p in err["loc"]) or None
        value = given.get(str(err["loc"][0])) if err["loc"] else given
        rule = "unknown parameter" if err["type"] == "extra_forbidden" else err["msg"]
        rule = rule.removeprefix("Value error, ")
        raise PluginParameterError(kind, name, param, value, rule) from None


ParamSource = Literal["default", "scenario"]


def param_sources(model: type[BaseModel], given: dict[str, Any]) -> dict[str, ParamSource]:
    """Each parameter of ``model``: ``scenario`` when its table ``given`` sets it, else
    ``default`` (the plug-in's own)."""
    out: dict[str, ParamSource] = {}
    for name, field in model.model_fields.items():
        shown = field.alias or name
        out[shown] = "scenario" if shown in given or name in given else "default"
    return out


# ----------------------------------------------------------------------------- checked calls


def _where(agents: Ints) -> str:
    ids = sorted(set(np.asarray(agents).tolist()))
    if len(ids) == 1:
        return f"agent {ids[0]}"
    shown = ", ".join(map(str, ids[:8])) + (", …" if len(ids) > 8 else "")
    return f"agents {shown}"


def _all_finite(values: Array) -> bool:
    """Every value finite, in one reduction: a NaN or inf makes the sum NaN or inf (so does an
    overflow of finite values, which the exact check that follows then clears)."""
    return math.isfinite(np.add.reduce(values, axis=None))


def fill_checked(
    name: str,
    strategy: LossStrategy,
    inputs: StrategyInputs,
    params: Any,
    receivers: Ints,
) -> Fill:
    """``strategy.fill`` with its answer checked; ``receivers`` (L,) are the links' agent ids."""
    try:
        out = strategy.fill(inputs, params)
    except Exception as exc:  # a user's code: any exception ends the run with its name
        raise PluginFailure(
            "strategy", name, _where(receivers), inputs.epoch, f"raised {type(exc).__name__}: {exc}"
        ) from exc
    n_links, d = inputs.received.shape
    if not isinstance(out, Fill):
        raise PluginFailure(
            "strategy",
            name,
            _where(receivers),
            inputs.epoch,
            f"returned {type(out).__name__}, not a Fill",
        )
    want = (
        (n_links, d),
        (n_links,),
        (n_links,),
        (n_links, inputs.state.shape[1]),
        (n_links,),
    )
    try:  # arrays, the common case: their shapes at attribute speed
        got = tuple(part.shape for part in out)  # Fill's fields, in order
    except AttributeError:
        got = tuple(np.shape(part) for part in out)
    if got != want:
        field, shape, wanted = next(
            (f, g, w) for f, g, w in zip(Fill._fields, got, want, strict=True) if g != w
        )
        raise PluginFailure(
            "strategy",
            name,
            _where(receivers),
            inputs.epoch,
            f"Fill.{field} has the shape {shape}; expected {wanted}",
        )
    if _all_finite(out.values):
        return out
    used = np.asarray(out.have, dtype=bool) & ~inputs.arrived
    bad = used & ~np.isfinite(out.values).all(axis=1)
    if bad.any():
        raise PluginFailure(
            "strategy",
            name,
            _where(receivers[bad]),
            inputs.epoch,
            "Fill.values is not finite (NaN or inf) for a link it fills",
        )
    return out


def command_checked(
    name: str, law: ControlLaw, inputs: ControlInputs, params: Any, agents: Ints, epoch: int
) -> Array:
    """``law.command`` with its answer checked; ``agents`` (n,) are the rows' agent ids."""
    try:
        out = law.command(inputs, params)
        if type(out) is not np.ndarray or out.dtype != np.float64:
            out = np.asarray(out, dtype=np.float64)
    except Exception as exc:  # a user's code: any exception ends the run with its name
        raise PluginFailure(
            "controller", name, _where(agents), epoch, f"raised {type(exc).__name__}: {exc}"
        ) from exc
    shape = (inputs.n, inputs.relative.shape[1])
    if out.shape != shape:
        raise PluginFailure(
            "controller",
            name,
            _where(agents),
            epoch,
            f"returned the shape {out.shape}; expected {shape}",
        )
    if _all_finite(out):
        return out
    bad = ~np.isfinite(out).all(axis=1)
    if bad.any():
        raise PluginFailure(
            "controller",
            name,
            _where(agents[bad]),
            epoch,
            "returned a command that is not finite (NaN or inf)",
        )
    return out


# ----------------------------------------------------------------------------- probes at load time


def _probe_links(dimension: int, width: int) -> tuple[StrategyInputs, Ints]:
    """Three in-links of two agents: one arrived, one lost with an estimate, one lost without."""
    rng = np.random.default_rng(0)
    d = dimension
    inputs = StrategyInputs(
        epoch=3,
        arrived=np.array([True, False, False]),
        received=np.vstack([rng.normal(size=(1, d)), np.zeros((2, d))]),
        last=rng.normal(size=(3, d)),
        last_epoch=np.array([2, 1, -1], dtype=np.int64),
        estimate=rng.normal(size=(3, d)),
        has_estimate=np.array([True, True, False]),
        v_ref_prev=np.full((3, d), 0.1),
        period_s=1.0,
        state=rng.normal(size=(3, width)),
        has_state=np.array([True, True, False]),
        lost=np.array([False, True, True]),
        has_last=np.array([True, True, False]),
    )
    return inputs, np.array([1, 1, 2], dtype=np.int64)


def probe_strategy(name: str, params: Any, dimension: int) -> None:
    """Call strategy ``name`` once on three made-up links; raise :class:`PluginError` if it fails."""
    strategy = loss_strategy(name)
    width = strategy.state_width(dimension)
    if not isinstance(width, int | np.integer) or width < 0:
        raise PluginError(
            "strategy", name, f"state_width({dimension}) = {width!r}; expected an int >= 0"
        )
    inputs, receivers = _probe_links(dimension, int(width))
    try:
        fill_checked(name, strategy, inputs, params, receivers)
    except PluginFailure as exc:
        raise PluginError("strategy", name, f"on a probe of 3 links: {exc.problem}") from None


def probe_controller(name: str, params: Any, dimension: int, dynamics: str) -> None:
    """Call controller ``name`` once on two made-up agents; raise :class:`PluginError` if it fails."""
    law = control_law(name)
    rng = np.random.default_rng(0)
    d = dimension
    inputs = ControlInputs(
        n=2,
        receivers=np.array([0, 0, 1], dtype=np.int64),
        relative=rng.normal(size=(3, d)),
        desired=rng.normal(size=(3, d)),
        distance_sq=np.ones(3),
        used=np.array([True, True, False]),
        epsilon=0.1,
        period_s=1.0,
        positions=rng.normal(size=(2, d)),
        velocities=np.zeros((2, d)),
        dynamics=dynamics,
        epoch=3,
        time_s=3.0,
    )
    try:
        command_checked(name, law, inputs, params, np.array([1, 2], dtype=np.int64), 3)
    except PluginFailure as exc:
        raise PluginError("controller", name, f"on a probe of 2 agents: {exc.problem}") from None


__all__ = [
    "CHAPTER_STRATEGIES",
    "DYNAMICS",
    "PLUGIN_EXIT",
    "PLUGIN_FAILED",
    "ControlInputs",
    "ControlLaw",
    "Fill",
    "LossStrategy",
    "NoParams",
    "ParamSource",
    "StrategyInputs",
    "all_strategies",
    "command_checked",
    "control_law",
    "fill_checked",
    "loss_strategy",
    "param_sources",
    "probe_controller",
    "probe_strategy",
    "validate_params",
]
