"""The scenario file (TOML) as one frozen pydantic model, loaded once and passed down.

``Scenario.from_file(path)`` reads and validates a file; every problem becomes a
:class:`~formation.errors.ScenarioError` naming the file, the field path and the
value. The model follows docs/model.md: §1 team and shape, §3 control, §4 edge rule,
§5 estimator, §6 strategy, §8 the default experiment (``scenarios/paper.toml``). Its
sections are in :mod:`formation.scenario_sections`, the checks that need the whole
scenario in :mod:`formation.scenario_checks`.
"""

from __future__ import annotations

import math
import tomllib
from functools import cached_property
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt
import tomli_w
from pydantic import BaseModel, ValidationError, model_validator

from formation._error_paths import loc_path, lookup
from formation.errors import NO_VALUE, ScenarioError
from formation.events import Membership, membership
from formation.keyed_random import Stream, keyed_normal
from formation.linkmodels import LinkModelSpec
from formation.plugin_api import CHAPTER_STRATEGIES
from formation.scenario_checks import link_stacks, problems
from formation.scenario_sections import FieldProblem, ScenarioFields, StrategyName
from formation.shipped_scenarios import resolve

# The chapter's strategies, in its order; ``--strategy all`` is every registered one (all_strategies).
STRATEGIES: tuple[str, ...] = CHAPTER_STRATEGIES


class Scenario(ScenarioFields):
    """A whole scenario. Agents are ids ``1..n``; row ``i − 1`` of every array is agent ``i``."""

    # -- checks that need the whole scenario ------------------------------------------------
    @model_validator(mode="after")
    def _check(self) -> Scenario:
        for problem in problems(self):
            raise FieldProblem(*problem)
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
        pairs = np.array([e.between for e in self.edges], dtype=np.int64).reshape(-1, 2)
        return np.sort(pairs, axis=1)

    @cached_property
    def weights(self) -> npt.NDArray[np.float64]:
        """Edge weights ``w_ij`` (the desired distances ``C_ij`` unless given): (m,) [m]."""
        ends = self.edge_array - 1
        diffs = self.offsets[ends[:, 0]] - self.offsets[ends[:, 1]]
        # The norm as np.linalg.norm takes it of one vector, sqrt(v·v): the same last bit
        # (a norm over an axis sums the squares in another order).
        return np.array(
            [
                e.weight if e.weight is not None else math.sqrt(v.dot(v))
                for e, v in zip(self.edges, diffs, strict=True)
            ],
            dtype=float,
        )

    @cached_property
    def noise_covariance(self) -> npt.NDArray[np.float64]:
        """``P_ij`` for every edge and epoch: (d, d) [m²]."""
        if self.noise.covariance is not None:
            return np.array(self.noise.covariance, dtype=float)
        return self.noise.sigma_m**2 * np.eye(self.dimension)

    def initial_positions(self, seed: int | None = None) -> npt.NDArray[np.float64]:
        """``x[0]``: shape + N(0, spread²) keyed by ``(seed, INITIAL, i, coord)``; the reference agent on its reference."""
        seed = self.seed if seed is None else seed
        ids = np.arange(1, self.n + 1)[:, None]
        coords = np.arange(self.dimension)[None, :]
        x0 = self.offsets + self.initial.spread_m * keyed_normal(seed, Stream.INITIAL, ids, coords)
        for a in self.agents:
            if a.initial is not None:
                x0[a.id - 1] = a.initial
        x0[self.reference_agent - 1] = self.offsets[self.reference_agent - 1]
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
        formation, control = link_stacks(self)
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


# Fields an older scenario file has under another name: old name → new name.
_RENAMED = {"leader": "reference_agent"}


def load_dict(data: dict[str, Any], source: str = "<scenario>") -> Scenario:
    """Validate a scenario given as a dict; errors name ``source``, the field path and the value."""
    for old, new in _RENAMED.items():
        if old in data:
            problem = f"this field is now called {new}"
            raise ScenarioError(source, old, data[old], problem)
    try:
        return Scenario.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        ctx = err.get("ctx") or {}
        inner = ctx.get("error")
        if isinstance(inner, FieldProblem):
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
    """Read a scenario TOML file, or the shipped scenario of that name (``paper``)."""
    path = resolve(path)
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


__all__ = ["STRATEGIES", "Scenario", "StrategyName", "load", "load_dict"]
