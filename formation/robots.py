"""The scenario's robot settings: unicycle limits, the safety envelope, and their checks.

A unicycle's pose is its look-ahead point ``p = c + l (cos θ, sin θ)`` (``c`` the wheel
axle's centre, ``l = lookahead_m``) and its heading ``θ``: the point is the agent's
coordination variable, so the consensus law is unchanged (``agent.control.step_unicycle``).
The defaults are a small ground robot's (about 0.2 m/s and 3.6 rad/s, 0.1 m across).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
from pydantic import BaseModel, ConfigDict, Field

from formation.keyed_random import Stream, keyed_uniform
from formation.linkmodels import LinkModelSpec, is_distance_spec

HEADING_SLOT = 1_000_000  # key word of the initial heading, beside the position coordinates 0..d-1


class _Settings(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class Unicycle(_Settings):
    """Speed limits and the near-identity transform's look-ahead of ``dynamics = "unicycle"``."""

    max_speed_m_s: float = Field(0.2, gt=0.0)  # linear [m/s]
    max_turn_rad_s: float = Field(3.6, gt=0.0)  # angular [rad/s]
    lookahead_m: float = Field(0.05, gt=0.0)  # l [m]
    inner_steps: int = Field(20, ge=1)  # speed commands per epoch (the robot's inner loop)

    @property
    def limits(self) -> tuple[float, float, float, int]:
        """``(max_speed_m_s, max_turn_rad_s, lookahead_m, inner_steps)``, as
        ``agent.control.drive_unicycle`` takes them."""
        return (self.max_speed_m_s, self.max_turn_rad_s, self.lookahead_m, self.inner_steps)


class Bounds(_Settings):
    """An axis-aligned box ``[min_m, max_m]`` per coordinate [m]."""

    min_m: tuple[float, ...]
    max_m: tuple[float, ...]


class Safety(_Settings):
    """What every run counts: collisions (closer than ``body_diameter_m``), time out of ``bounds``."""

    body_diameter_m: float = Field(0.1, ge=0.0)  # [m]; 0: no collision is counted
    bounds: Bounds | None = None


def initial_headings(seed: int, n: int) -> npt.NDArray[np.float64]:
    """``θ[0]`` ``(n,)`` [rad] in ``[−π, π)``, keyed by ``(seed, INITIAL, i, HEADING_SLOT)``."""
    ids = np.arange(1, n + 1, dtype=np.int64)
    return np.asarray(
        (keyed_uniform(seed, int(Stream.INITIAL), ids, HEADING_SLOT) - 0.5) * 2.0 * math.pi,
        dtype=np.float64,
    )


def is_distance_model(spec: LinkModelSpec) -> bool:
    return is_distance_spec(spec)


def robot_problems(
    dimension: int,
    dynamics: str,
    mode: str,
    safety: Safety,
    access_point: Sequence[float] | None,
    edge_lengths: Sequence[tuple[str, float]],
    formation_stacks: Sequence[tuple[str, Sequence[LinkModelSpec]]],
    control_stacks: Sequence[tuple[str, Sequence[LinkModelSpec]]],
) -> list[tuple[str, object, str]]:
    """``(field, value, problem)`` of the robot and wireless settings; empty when they can run.

    ``edge_lengths`` are ``(name, ||d0_i − d0_j||)`` per edge; the stacks ``(field, models)``.
    """
    if dynamics == "unicycle" and dimension != 2:
        return [
            (
                "control.dynamics",
                dynamics,
                f"a unicycle moves in a plane; dimension = {dimension}, expected 2",
            )
        ]
    if edge_lengths:
        name, shortest = min(edge_lengths, key=lambda e: e[1])
        if safety.body_diameter_m > shortest:
            return [
                (
                    "safety.body_diameter_m",
                    safety.body_diameter_m,
                    f"larger than the shape's shortest edge ({name}: {shortest:g} m): "
                    "the robots could not hold the shape without touching",
                )
            ]
    b = safety.bounds
    if b is not None:
        for name, corner in (("min_m", b.min_m), ("max_m", b.max_m)):
            if len(corner) != dimension:
                return [
                    (f"safety.bounds.{name}", list(corner), f"expected {dimension} coordinates")
                ]
        if any(lo >= hi for lo, hi in zip(b.min_m, b.max_m, strict=True)):
            return [
                (
                    "safety.bounds.max_m",
                    list(b.max_m),
                    f"expected > min_m = {list(b.min_m)} in every coordinate",
                )
            ]
    if access_point is not None and len(access_point) != dimension:
        return [("network.access_point", list(access_point), f"expected {dimension} coordinates")]
    for field, stack in (*formation_stacks, *control_stacks):
        for k, spec in enumerate(stack):
            if is_distance_model(spec) and mode == "realtime":
                return [
                    (
                        f"{field}[{k}].model",
                        spec.model,
                        "a distance model needs runtime.mode = 'lockstep'",
                    )
                ]
    if access_point is None:
        for field, stack in control_stacks:
            for k, spec in enumerate(stack):
                if is_distance_model(spec):
                    return [
                        (
                            f"{field}[{k}].model",
                            spec.model,
                            "a distance model on a control link needs network.access_point (the leader's radio)",
                        )
                    ]
    return []


__all__ = [
    "HEADING_SLOT",
    "Bounds",
    "Safety",
    "Unicycle",
    "initial_headings",
    "is_distance_model",
    "robot_problems",
]
