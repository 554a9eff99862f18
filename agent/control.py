"""Discrete formation control (docs/model.md §3) and the agents' dynamics.

All functions work on a batch of directed in-links ``j → i`` at once, so one
agent (its own in-links) and a whole team (every link) run the same code. The two laws
are controller plug-ins (``formation.plugin_api.ControlLaw``), registered by entry point
like a user's: ``DISPLACEMENT`` and ``DISTANCE``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from formation.plugin_api import ControlInputs, ControlLaw

Array = npt.NDArray[np.float64]


def displacement_command(
    n: int,
    receivers: npt.NDArray[np.int64],
    relative: Array,
    desired: Array,
    used: npt.NDArray[np.bool_],
    epsilon: float,
) -> Array:
    """Consensus on ``r_i = x_i − d0_i``: ``−ε Σ_j [z̃_ij − (d0_i − d0_j)]`` per agent.

    Parameters
    ----------
    n : number of agents in the batch (rows of the result)
    receivers : (L,) row index of the receiving agent ``i`` of each in-link
    relative : (L, d) the relative value ``z̃_ij`` used for each link [m]
    desired : (L, d) ``d0_i − d0_j`` [m]
    used : (L,) False where the term is left out (``drop``, or nothing to substitute)
    epsilon : ``ε = k T``

    Returns
    -------
    (n, d) position increment [m]
    """
    terms = np.where(used[:, None], relative - desired, 0.0)
    return -epsilon * _per_agent(n, receivers, terms)


def distance_command(
    n: int,
    receivers: npt.NDArray[np.int64],
    relative: Array,
    distance_sq: Array,
    used: npt.NDArray[np.bool_],
    epsilon: float,
) -> Array:
    """Distance-based law (docs/model.md §2 note): ``−ε Σ_j (||z̃_ij||² − C_ij²) z̃_ij``.

    ``distance_sq`` is (L,) ``C_ij²`` [m²]; the other arguments as in :func:`displacement_command`.
    """
    gap = np.einsum("ld,ld->l", relative, relative) - distance_sq
    terms = np.where(used[:, None], gap[:, None] * relative, 0.0)
    return -epsilon * _per_agent(n, receivers, terms)


def _per_agent(n: int, receivers: npt.NDArray[np.int64], terms: Array) -> Array:
    """(n, d) each agent's sum of its links' ``terms`` (L, d), added in link order from 0.0.

    The order and the floats of ``np.add.at``; ``np.bincount`` adds a column at a time.
    """
    out = np.empty((n, terms.shape[1]))
    for c in range(terms.shape[1]):
        out[:, c] = np.bincount(receivers, weights=terms[:, c], minlength=n)
    return out


def _displacement(x: ControlInputs, params: Any) -> Array:
    return displacement_command(x.n, x.receivers, x.relative, x.desired, x.used, x.epsilon)


def _distance(x: ControlInputs, params: Any) -> Array:
    return distance_command(x.n, x.receivers, x.relative, x.distance_sq, x.used, x.epsilon)


DISPLACEMENT = ControlLaw(_displacement, description="consensus on x_i − d0_i (docs/model.md §3)")
DISTANCE = ControlLaw(
    _distance, description="gradient of Σ (||z_ij||² − C_ij²)² (docs/model.md §2)"
)


def step_single(x: Array, command: Array, v_ref: Array, period_s: float) -> Array:
    """Single integrator: ``x[k+1] = x[k] + command + T v_ref[k]``."""
    return x + command + period_s * v_ref


def step_double(
    x: Array, v: Array, command: Array, v_ref: Array, period_s: float, damping: float
) -> tuple[Array, Array]:
    """Double integrator, semi-implicit Euler.

    The consensus increment acts as an acceleration ``a = command / T² − c (v − v_ref)``
    (``command`` is ``−ε Σ…`` with ``ε = k T``, so ``a = −(k/T) Σ…``); then
    ``v[k+1] = v + T a`` and ``x[k+1] = x + T v[k+1]``.
    """
    accel = command / period_s**2 - damping * (v - v_ref)
    v_next = v + period_s * accel
    return x + period_s * v_next, v_next


def step_unicycle(
    x: Array,
    heading: Array,
    command: Array,
    v_ref: Array,
    period_s: float,
    limits: tuple[float, float, float, int],
) -> tuple[Array, Array, npt.NDArray[np.int64]]:
    """Unicycles driven through the near-identity transform, with speed limits.

    The agent's position is its look-ahead point ``p = c + l h(θ)``, ``h(θ) = (cos θ,
    sin θ)``, ``c`` the axle's centre. The consensus step asks ``p`` to move at
    ``u = command / T + v_ref`` (:func:`lookahead_velocity`); the rest is
    :func:`drive_unicycle`.

    Parameters
    ----------
    x : (a, 2) look-ahead points ``p[k]`` [m]
    heading : (a,) ``θ[k]`` [rad]
    command : (a, 2) consensus increment [m]; v_ref : (a, 2) [m/s]
    period_s : ``T`` [s]
    limits : ``(max_speed_m_s, max_turn_rad_s, lookahead_m, inner_steps)``

    Returns
    -------
    (a, 2) ``p[k+1]`` [m], (a,) ``θ[k+1]`` in ``[−π, π)`` [rad], (a,) sub-steps with a clipped speed
    """
    u = lookahead_velocity(command, v_ref, period_s)
    return drive_unicycle(x, heading, u, period_s, limits)


def lookahead_velocity(command: Array, v_ref: Array, period_s: float) -> Array:
    """The velocity the consensus step asks of a unicycle's look-ahead point,
    ``u = command / T + v_ref``: (a, 2) [m/s] (command [m], v_ref [m/s])."""
    return command / period_s + v_ref


def drive_unicycle(
    x: Array, heading: Array, u: Array, period_s: float, limits: tuple[float, float, float, int]
) -> tuple[Array, Array, npt.NDArray[np.int64]]:
    """Unicycles whose look-ahead points are driven at ``u`` for one period.

    The transform (Robotarium's ``si_to_uni``, Olfati-Saber's near-identity diffeomorphism)
    gives ``v = h · u`` and ``ω = h⊥ · u / l``, ``h⊥ = (−sin θ, cos θ)``, under which
    ``ṗ = u`` exactly. ``v``, ``ω`` are clipped to the limits, recomputed from the heading
    at each of ``inner_steps`` sub-steps of ``T / inner_steps`` and held over it, while the
    unicycle ``ċ = v h(θ)``, ``θ̇ = ω`` moves along an exact arc (:func:`unicycle_substep`).
    The heading is wrapped once, at the period's end. A robot's inner loop does the same
    pose by pose (docs/robots.md).

    x : (a, 2) ``p[k]`` [m]; heading : (a,) ``θ[k]`` [rad]; u : (a, 2) [m/s]. Returns as
    :func:`step_unicycle`.
    """
    look = limits[2]
    dt = substep_s(period_s, limits)
    p, th = x.copy(), heading.copy()
    saturated = np.zeros(x.shape[0], dtype=np.int64)
    for _ in range(limits[3]):
        v, w, clipped = unicycle_twist(th, u, limits)
        saturated += clipped
        _, th, p = unicycle_substep(p, th, v, w, dt, look)
    return p, wrap_angle(th), saturated


def substep_s(period_s: float, limits: tuple[float, float, float, int]) -> float:
    """One sub-step of a unicycle's inner loop, ``T / inner_steps`` [s]."""
    return period_s / limits[3]


def unicycle_substep(
    p: Array, heading: Array, v: Array, w: Array, dt_s: float, lookahead_m: float
) -> tuple[Array, Array, Array]:
    """One sub-step of :func:`drive_unicycle` from look-ahead points ``p`` and ``heading``,
    holding ``v``, ``ω`` for ``dt_s``: the axle's centre, the heading (not wrapped) and the
    look-ahead point after it.

    p : (a, 2) [m]; heading, v, w : (a,) [rad], [m/s], [rad/s]. The centre is recomputed from
    ``p`` at each sub-step (a float round trip the stepped plant repeats to stay bit-equal).
    """
    centre = axle_centre(p, heading, lookahead_m)
    centre, heading = unicycle_arc(centre, heading, v, w, dt_s)
    return centre, heading, lookahead_point(centre, heading, lookahead_m)


def axle_centre(p: Array, heading: Array, lookahead_m: float) -> Array:
    """``c = p − l h(θ)``: (a, 2) axle centres of look-ahead points ``p`` (a, 2) [m]."""
    return p - lookahead_m * heading_vector(heading)


def lookahead_point(centre: Array, heading: Array, lookahead_m: float) -> Array:
    """``p = c + l h(θ)``: (a, 2) look-ahead points of axle centres ``c`` (a, 2) [m]."""
    return centre + lookahead_m * heading_vector(heading)


def heading_vector(heading: Array) -> Array:
    """``h(θ) = (cos θ, sin θ)``: (a, 2) for (a,) headings [rad]."""
    return np.stack([np.cos(heading), np.sin(heading)], axis=1)


def wrap_angle(angle: Array) -> Array:
    """An angle in ``[−π, π)`` [rad]."""
    return np.asarray(np.mod(angle + np.pi, 2.0 * np.pi) - np.pi, dtype=np.float64)


def unicycle_twist(
    heading: Array, u: Array, limits: tuple[float, float, float, int]
) -> tuple[Array, Array, npt.NDArray[np.bool_]]:
    """The speeds that move the look-ahead point at ``u``: ``v = h · u``, ``ω = h⊥ · u / l``,
    clipped to the limits (:func:`drive_unicycle`'s inner loop; a robot's ``Twist``).

    heading : (a,) [rad]; u : (a, 2) [m/s]. Returns (a,) ``v`` [m/s], (a,) ``ω`` [rad/s] and
    (a,) whether either was clipped.
    """
    v_max, w_max, look, _ = limits
    cos, sin = np.cos(heading), np.sin(heading)
    v_want = cos * u[:, 0] + sin * u[:, 1]
    w_want = (cos * u[:, 1] - sin * u[:, 0]) / look
    v, w = np.clip(v_want, -v_max, v_max), np.clip(w_want, -w_max, w_max)
    return v, w, (v != v_want) | (w != w_want)


def unicycle_arc(
    centre: Array, heading: Array, v: Array, w: Array, dt_s: float
) -> tuple[Array, Array]:
    """The axle's centre and heading after holding ``v``, ``ω`` for ``dt_s``: an exact arc.

    centre : (a, 2) [m]; heading, v, w : (a,) [rad], [m/s], [rad/s]. The heading is not wrapped.
    """
    turn = w * dt_s
    mid = heading + 0.5 * turn
    arc = v * dt_s * np.sinc(turn / (2.0 * np.pi))  # chord of the arc: v dt sin(Δ/2) / (Δ/2)
    return centre + arc[:, None] * heading_vector(mid), heading + turn


def reference_heading(heading: Array, step_m: Array) -> Array:
    """The reference agent's heading: the direction it moved in, unchanged while at rest.

    The reference agent follows its trajectory (docs/model.md §3) instead of its unicycle's
    step; its heading follows that motion. heading : (a,) [rad]; step_m : (a, 2) or (2,) ``x[k+1] − x[k]`` [m].
    """
    moving = np.any(step_m != 0.0, axis=-1)
    return np.asarray(
        np.where(moving, np.arctan2(step_m[..., 1], step_m[..., 0]), heading), dtype=np.float64
    )


def held_velocity_step(x: Array, velocity: Array, period_s: float) -> Array:
    """A holonomic body that holds ``velocity`` for ``period_s``: :func:`step_single` with
    no consensus increment and the velocity as its feed-forward, ``x + T u``.

    x : (a, d) [m]; velocity : (a, d) [m/s]. What a velocity-driven robot does with one
    ``Twist``, and what the ROS 2 plant integrates (docs/robots.md).
    """
    return step_single(x, np.zeros_like(x), velocity, period_s)


def body_velocity(x: Array, x_next: Array, period_s: float) -> Array:
    """The velocity a robot is sent to take it from ``x`` to ``x_next`` in one period,
    ``(x_next − x) / T``: (a, d) [m/s]."""
    return (x_next - x) / period_s


def body_step(x: Array, x_next: Array, period_s: float) -> Array:
    """Where a velocity-driven robot sent toward ``x_next`` is after one period: (a, d) [m].

    ``x + T ((x_next − x) / T)``, which differs from ``x_next`` in the last bits; the
    simulator moves an agent whose body is a robot by this (docs/robots.md), so that a run
    through the stepped ROS 2 plant equals it to the bit.
    """
    return held_velocity_step(x, body_velocity(x, x_next, period_s), period_s)
