"""The reference trajectory (docs/model.md §3): static, line, circle, waypoints.

In formation/ rather than leader/ because both the leader (v_ref for the
followers) and the reference agent (its own motion) evaluate it.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from formation.scenario_sections import (
    CircleReference,
    LineReference,
    Reference,
    StaticReference,
    WaypointReference,
)


def reference_positions(
    reference: Reference, start: npt.ArrayLike, period_s: float, n_epochs: int
) -> npt.NDArray[np.float64]:
    """Leader positions ``x_r[k]`` for ``k = 0..n_epochs`` (inclusive).

    Parameters
    ----------
    reference : the scenario's reference trajectory
    start : (d,) array [m], the leader's position at epoch 0
    period_s : epoch period T [s]
    n_epochs : number of epochs; the result has ``n_epochs + 1`` rows

    Returns
    -------
    (n_epochs + 1, d) array [m]
    """
    x0 = np.asarray(start, dtype=float)
    t = np.arange(n_epochs + 1, dtype=float) * period_s  # [s]
    if isinstance(reference, StaticReference):
        return np.tile(x0, (n_epochs + 1, 1))
    if isinstance(reference, LineReference):
        return np.asarray(
            x0 + t[:, None] * np.asarray(reference.velocity, dtype=float), dtype=float
        )
    if isinstance(reference, CircleReference):
        # The leader starts on the circle at angle 0 around a centre radius_m to its -x side.
        angle = reference.angular_velocity * t
        out = np.tile(x0, (n_epochs + 1, 1))
        out[:, 0] += reference.radius_m * (np.cos(angle) - 1.0)
        out[:, 1] += reference.radius_m * np.sin(angle)
        return out
    if isinstance(reference, WaypointReference):
        return _waypoints(reference, x0, t)
    raise TypeError(f"unknown reference {reference!r}")


def _waypoints(
    ref: WaypointReference, x0: npt.NDArray[np.float64], t: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    points = np.vstack([x0, np.asarray(ref.points, dtype=float)])
    if ref.loop:
        points = np.vstack([points, x0])
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])  # [m] along the path
    s = ref.speed_m_s * t
    if ref.loop and arc[-1] > 0:
        s = np.mod(s, arc[-1])
    s = np.clip(s, 0.0, arc[-1])
    return np.stack([np.interp(s, arc, points[:, c]) for c in range(points.shape[1])], axis=1)


def reference_velocities(
    positions: npt.NDArray[np.float64], period_s: float
) -> npt.NDArray[np.float64]:
    """``v_ref[k] = (x_r[k+1] − x_r[k]) / T``: (n_epochs, d) [m/s], so ``x + T v_ref`` tracks exactly."""
    return np.diff(positions, axis=0) / period_s
