"""The checks that need a whole scenario: each a function returning its problems.

:data:`CHECKS` runs in order and :func:`problems` stops at the first check that finds
one, so a check may rely on every check before it (the ids are ``1..n``, the edges join
agents that exist, ...). A problem is ``(field path, value, what is wrong)``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt
from pydantic import BaseModel

from formation.air import air_problems
from formation.body import body_problems
from formation.capacity import capacity_problems
from formation.errors import PluginError
from formation.events import event_problems
from formation.graph import is_connected, max_degree
from formation.plugin_api import probe_controller, probe_strategy
from formation.rigidity import (
    SVD_MAX_COLUMNS,
    distance_epsilon_bound,
    expected_rigidity_rank,
    rigidity_rank,
)
from formation.rigidity_check import is_rigid
from formation.robots import robot_problems
from formation.scenario_sections import LineReference, ScenarioFields, WaypointReference

Problem = tuple[str, object, str]  # (field path, value, what is wrong)


# The model is frozen and compared with ``==``: a check computes what it needs here rather
# than through the scenario's cached properties.
def _offsets(s: ScenarioFields) -> npt.NDArray[np.float64]:
    return np.array([a.offset for a in s.agents], dtype=float)


def _pairs(s: ScenarioFields) -> npt.NDArray[np.int64]:
    return np.array([sorted(e.between) for e in s.edges], dtype=np.int64).reshape(-1, 2)


def _agent_ids(s: ScenarioFields) -> list[Problem]:
    n, ids = len(s.agents), [a.id for a in s.agents]
    if sorted(ids) != list(range(1, n + 1)):
        return [("agents", ids, f"agent ids must be 1..{n} without gaps or repeats")]
    if ids != sorted(ids):
        return [("agents", ids, "list the agents in id order")]
    return []


def _agent_coordinates(s: ScenarioFields) -> list[Problem]:
    d = s.dimension
    for k, a in enumerate(s.agents):
        if len(a.offset) != d:
            return [(f"agents[{k}].offset", list(a.offset), f"expected {d} coordinates")]
        if a.initial is not None and len(a.initial) != d:
            return [(f"agents[{k}].initial", list(a.initial), f"expected {d} coordinates")]
    return []


def _reference_agent(s: ScenarioFields) -> list[Problem]:
    n = len(s.agents)
    if not 1 <= s.reference_agent <= n:
        return [("reference_agent", s.reference_agent, f"no agent has this id (agents are 1..{n})")]
    return []


def _edge_ends(s: ScenarioFields) -> list[Problem]:
    n = len(s.agents)
    seen: set[tuple[int, int]] = set()
    for k, e in enumerate(s.edges):
        for i in e.between:
            if not 1 <= i <= n:
                problem = f"agent {i} does not exist (agents are 1..{n})"
                return [(f"edges[{k}].between", list(e.between), problem)]
        key = (min(e.between), max(e.between))
        if key in seen:
            return [(f"edges[{k}].between", list(e.between), "edge listed twice")]
        seen.add(key)
    return []


def _edge_lengths_nonzero(s: ScenarioFields) -> list[Problem]:
    d0 = _offsets(s)
    for k, (i, j) in enumerate(_pairs(s)):
        if np.linalg.norm(d0[i - 1] - d0[j - 1]) == 0.0:
            problem = "the two agents have the same offset"
            return [(f"edges[{k}].between", [int(i), int(j)], problem)]
    return []


def _connected(s: ScenarioFields) -> list[Problem]:
    n, pairs = len(s.agents), _pairs(s)
    if n > 1 and not is_connected(n, pairs):
        edges = [list(map(int, p)) for p in pairs]
        return [("edges", edges, "the formation graph is not connected")]
    return []


def _rigid(s: ScenarioFields) -> list[Problem]:
    n, d = len(s.agents), s.dimension
    if n <= 1 or s.allow_flexible:
        return []
    d0, pairs = _offsets(s), _pairs(s)
    if is_rigid(d0, pairs):
        return []
    need = expected_rigidity_rank(n, d)
    have = f"rigidity rank {rigidity_rank(d0, pairs)}" if n * d <= SVD_MAX_COLUMNS else "not rigid"
    problem = (
        f"the shape is not rigid ({have}, need {need}); add edges or set allow_flexible = true"
    )
    return [("edges", f"{len(pairs)} edges", problem)]


def _stable_gain(s: ScenarioFields) -> list[Problem]:
    n = len(s.agents)
    if s.control.controller == "distance":
        return _stable_distance_gain(s)
    delta = max_degree(n, _pairs(s)) if n > 1 else 0
    eps = s.control.epsilon
    if delta > 0 and eps >= 1.0 / delta:
        problem = (
            f"epsilon = gain * period_s = {eps:g} must be < 1/max_degree = 1/{delta} = "
            f"{1.0 / delta:g}"
        )
        return [("control.gain", s.control.gain, problem)]
    return []


def _stable_distance_gain(s: ScenarioFields) -> list[Problem]:
    """The distance law's step bound on the shape (docs/model.md §3): ``ε < 1/λ_max((RᵀR)_F)``."""
    bound = distance_epsilon_bound(_offsets(s), _pairs(s), s.reference_agent)
    eps = s.control.epsilon
    if eps >= bound:
        problem = (
            f"epsilon = gain * period_s = {eps:g} must be < {bound:.4g} = 1/lambda_max of the "
            "shape's R^T R over the followers, the distance controller's stable step "
            f"(gain < {bound / s.control.period_s:.4g})"
        )
        return [("control.gain", s.control.gain, problem)]
    return []


def _reference_coordinates(s: ScenarioFields) -> list[Problem]:
    d, ref = s.dimension, s.reference
    if isinstance(ref, LineReference) and len(ref.velocity) != d:
        return [("reference.velocity", list(ref.velocity), f"expected {d} coordinates")]
    if isinstance(ref, WaypointReference):
        for k, p in enumerate(ref.points):
            if len(p) != d:
                return [(f"reference.points[{k}]", list(p), f"expected {d} coordinates")]
    return []


def _noise_covariance(s: ScenarioFields) -> list[Problem]:
    d, given = s.dimension, s.noise.covariance
    if given is None:
        return []
    cov = np.array(given, dtype=float)
    if cov.shape != (d, d):
        return [("noise.covariance", given, f"expected a {d}x{d} matrix")]
    if not np.allclose(cov, cov.T) or np.min(np.linalg.eigvalsh(cov)) <= 0.0:
        return [("noise.covariance", given, "expected a symmetric positive definite matrix")]
    return []


def _links_on_edges(s: ScenarioFields) -> list[Problem]:
    edge_set = {(int(i), int(j)) for i, j in _pairs(s)}
    for k, link in enumerate(s.network.links):
        if (min(link.between), max(link.between)) not in edge_set:
            problem = "not an edge of the formation graph"
            return [(f"network.links[{k}].between", list(link.between), problem)]
    return []


def _control_agents(s: ScenarioFields) -> list[Problem]:
    n = len(s.agents)
    for k, c in enumerate(s.network.control):
        if not 1 <= c.agent <= n:
            problem = f"agent does not exist (agents are 1..{n})"
            return [(f"network.control[{k}].agent", c.agent, problem)]
    return []


def _capacity(s: ScenarioFields) -> list[Problem]:
    directed = [(int(i), int(j)) for a, b in _pairs(s) for i, j in ((a, b), (b, a))]
    return capacity_problems(s.network.capacity, len(s.agents), directed)


def _air(s: ScenarioFields) -> list[Problem]:
    air, network = s.network.air, s.network
    return air_problems(
        air, network.access_point, s.runtime.mode, bool(network.capacity), bool(s.events)
    )


def _events(s: ScenarioFields) -> list[Problem]:
    n = len(s.agents)
    return event_problems(n, s.reference_agent, s.epochs, _pairs(s), s.events, s.allow_split)


def _body(s: ScenarioFields) -> list[Problem]:
    return body_problems(s.body, len(s.agents))


def _plugins(s: ScenarioFields) -> list[Problem]:
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


def _robots(s: ScenarioFields) -> list[Problem]:
    d0 = _offsets(s)
    lengths = [
        (f"{i}–{j}", float(np.linalg.norm(d0[i - 1] - d0[j - 1]))) for i, j in _pairs(s).tolist()
    ]
    return robot_problems(
        s.dimension,
        s.control.dynamics,
        s.runtime.mode,
        s.safety,
        s.network.access_point,
        lengths,
        *link_stacks(s),
    )


def link_stacks(s: ScenarioFields) -> tuple[list[tuple[str, Any]], list[tuple[str, Any]]]:
    """The formation and control link stacks as ``(field, models)``."""
    net = s.network
    formation = [("network.formation_default", net.formation_default)]
    formation += [(f"network.links[{k}].models", link.models) for k, link in enumerate(net.links)]
    control = [("network.control_default", net.control_default)]
    control += [(f"network.control[{k}].models", c.models) for k, c in enumerate(net.control)]
    return formation, control


CHECKS: tuple[Callable[[ScenarioFields], list[Problem]], ...] = (
    _agent_ids,
    _agent_coordinates,
    _reference_agent,
    _edge_ends,
    _edge_lengths_nonzero,
    _connected,
    _rigid,
    _stable_gain,
    _reference_coordinates,
    _noise_covariance,
    _links_on_edges,
    _control_agents,
    _capacity,
    _air,
    _events,
    _body,
    _plugins,
    _robots,
)


def problems(s: ScenarioFields) -> list[Problem]:
    """The problems of the first check in :data:`CHECKS` that finds any."""
    for check in CHECKS:
        found = check(s)
        if found:
            return found
    return []
