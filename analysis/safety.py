"""Safety counts of a run, as ``summary.json``, ``report.md`` and the run summary give them.

From the true positions (``analysis.metrics``: :func:`min_distance`, :func:`collisions`,
:func:`time_out_of_bounds`) and, for unicycles, the recorded headings and saturation counts.
Epochs with a missing state (an agent out of the team) leave that agent out of the epoch's
distances.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from analysis.membership import present
from analysis.metrics import collisions, min_distance, time_out_of_bounds
from formation.scenario import Scenario

Array = npt.NDArray[np.float64]


def safety_counts(
    scenario: Scenario,
    positions: Array,
    headings: Array | None = None,
    saturated: npt.NDArray[np.int64] | None = None,
) -> dict[str, Any]:
    """The run's safety numbers, JSON-ready.

    Parameters
    ----------
    scenario : its ``safety`` (body diameter, bounds), ``control`` (period, unicycle limits)
    positions : (T, n, d) true positions [m], NaN where not recorded
    headings : (T, n) [rad], NaN where not recorded (unicycle only)
    saturated : (T, n) sub-steps of each epoch with a clipped speed, −1 where not recorded

    Returns
    -------
    ``min_distance_m`` (the least over the run), ``min_distance_per_epoch_m`` (T,),
    ``body_diameter_m``, ``collisions`` per pair ``"i-j"`` (pairs with one or more),
    ``collisions_total``, ``time_out_of_bounds_s`` per agent (with bounds), and for unicycles
    ``saturated_steps`` per agent and ``max_speed_m_s`` (the fastest axle speed seen,
    each epoch's chord of the axle's path over ``T``) against ``max_speed_limit_m_s``, and
    ``max_turn_rad_s`` (:func:`turn_rates`, the reference agent aside: it turns with the
    reference trajectory) against ``max_turn_limit_rad_s``.
    """
    safety, period = scenario.safety, scenario.control.period_s
    per_epoch = min_distance(positions) if len(positions) else np.zeros(0)
    finite = per_epoch[np.isfinite(per_epoch)]
    pairs, counts = collisions(positions, safety.body_diameter_m)  # a missing agent: no contact
    out: dict[str, Any] = {
        "min_distance_m": float(finite.min()) if finite.size else None,
        "min_distance_per_epoch_m": [None if not math.isfinite(v) else float(v) for v in per_epoch],
        "body_diameter_m": safety.body_diameter_m,
        "collisions": {f"{a}-{b}": int(c) for (a, b), c in zip(pairs, counts, strict=True)},
        "collisions_total": int(counts.sum()),
    }
    if safety.bounds is not None:
        low, high = np.asarray(safety.bounds.min_m), np.asarray(safety.bounds.max_m)
        seen = present(positions)[..., None]
        inside = np.where(seen, positions, (low + high) / 2.0)  # not recorded: not counted
        out_s = time_out_of_bounds(inside, low, high, period)
        out["time_out_of_bounds_s"] = {str(i + 1): float(v) for i, v in enumerate(out_s)}
    if headings is not None and saturated is not None:
        uni = scenario.control.unicycle
        out["saturated_steps"] = {
            str(i + 1): int(np.clip(saturated[:, i], 0, None).sum())
            for i in range(saturated.shape[1])
        }
        speed = axle_speeds(positions, headings, uni.lookahead_m, period)
        out["max_speed_m_s"] = float(np.nanmax(speed)) if np.isfinite(speed).any() else None
        out["max_speed_limit_m_s"] = uni.max_speed_m_s
        turn = turn_rates(headings, period)
        turn[:, scenario.reference_agent - 1] = (
            np.nan
        )  # the reference agent turns with the reference
        out["max_turn_rad_s"] = float(np.nanmax(turn)) if np.isfinite(turn).any() else None
        out["max_turn_limit_rad_s"] = uni.max_turn_rad_s
    return out


def axle_speeds(positions: Array, headings: Array, lookahead_m: float, period_s: float) -> Array:
    """Each epoch's mean axle speed: ``||c[k+1] − c[k]|| / T``, ``c = p − l (cos θ, sin θ)``.

    positions : (T, n, 2) look-ahead points [m]; headings : (T, n) [rad]. Returns (T − 1, n)
    [m/s], NaN where a state is missing. The chord is no longer than the path, so a speed
    limit that holds on every sub-step holds here.
    """
    centre = positions - lookahead_m * np.stack([np.cos(headings), np.sin(headings)], axis=-1)
    step = np.diff(centre, axis=0)
    return np.asarray(np.sqrt(np.sum(step * step, axis=-1)) / period_s, dtype=np.float64)


def turn_rates(headings: Array, period_s: float) -> Array:
    """Each epoch's turn rate as the recording shows it: ``|wrap(θ[k+1] − θ[k])| / T``.

    headings : (T, n) [rad]. Returns (T − 1, n) [rad/s], NaN where a heading is missing.
    The wrapped change is never more than the angle turned, so a turn limit that holds on
    every sub-step holds here too; above ``π / T`` the limit cannot be seen from headings.
    """
    change = np.mod(np.diff(headings, axis=0) + np.pi, 2.0 * np.pi) - np.pi
    return np.asarray(np.abs(change) / period_s, dtype=np.float64)


SAFETY_ROWS = (
    ("min inter-agent distance [m]", "min_distance_m"),
    ("collisions (pairs closer than the body)", "collisions_total"),
)


def safety_lines(label: str, s: dict[str, Any]) -> list[str]:
    """``report.md`` lines of one run's :func:`safety_counts`."""
    md = s["min_distance_m"]
    parts = [
        f"min inter-agent distance {'–' if md is None else f'{md:.4g}'} m "
        f"(body {s['body_diameter_m']:g} m)",
        f"collisions {s['collisions_total']}"
        + (
            " (" + ", ".join(f"{p}: {c}" for p, c in s["collisions"].items()) + ")"
            if s["collisions"]
            else ""
        ),
    ]
    if "time_out_of_bounds_s" in s:
        out = {a: t for a, t in s["time_out_of_bounds_s"].items() if t}
        parts.append(
            "time out of bounds "
            + (", ".join(f"agent {a}: {t:g} s" for a, t in out.items()) if out else "none")
        )
    if "saturated_steps" in s:
        sat = sum(s["saturated_steps"].values())
        top = s["max_speed_m_s"]
        parts.append(
            f"saturated sub-steps {sat}, fastest axle {'–' if top is None else f'{top:.4g}'} m/s"
            f" (limit {s['max_speed_limit_m_s']:g})"
        )
        turn = s.get("max_turn_rad_s")
        parts.append(
            f"fastest turn {'–' if turn is None else f'{turn:.4g}'} rad/s"
            f" (limit {s['max_turn_limit_rad_s']:g})"
        )
    return [f"- {label}: " + "; ".join(parts)]


__all__ = ["SAFETY_ROWS", "axle_speeds", "safety_counts", "safety_lines", "turn_rates"]
