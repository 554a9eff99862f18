"""An agent's messages as JSON, built with orjson: a pool of hundreds sends one per agent and
epoch, and the pydantic model cost more than the rest of its step. Each equals what its wire
model (:mod:`formation.messages`) validates."""

from __future__ import annotations

from typing import Any

import orjson

Report = list[tuple[int, int, list[float] | None]]  # (neighbour, token, z_ij) per in-link


def state_message(
    head: dict[str, Any],
    agent: int,
    position: list[float],
    substituted: list[tuple[int, list[float], bool]],
    pose: tuple[float, int] | None = None,
    robot_silent: bool = False,
) -> bytes:
    """A :class:`~formation.messages.CoordinationState` as JSON.
    ``pose``: a unicycle's heading [rad] and saturated sub-steps (omitted for point agents);
    ``robot_silent``: sent late as the agent waited for its robot's pose (else omitted)."""
    msg = {
        **head,
        "kind": "state",
        "agent": agent,
        "position": position,
        "velocity": None,
        "substituted": [{"neighbour": j, "value": v, "fallback": f} for j, v, f in substituted],
    }
    if pose is not None:
        msg["heading"], msg["saturated"] = pose
    if robot_silent:
        msg["robot_silent"] = True
    return orjson.dumps(msg)


def report_message(
    head: dict[str, Any], agent: int, report: Report, robot_silent: bool = False
) -> bytes:
    """A :class:`~formation.messages.TokenReport` as JSON."""
    msg = {
        **head,
        "kind": "report",
        "agent": agent,
        "measurements": [{"neighbour": j, "token": 1 if t else 0, "z": z} for j, t, z in report],
    }
    if robot_silent:
        msg["robot_silent"] = True
    return orjson.dumps(msg)
