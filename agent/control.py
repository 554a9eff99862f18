"""Discrete formation control (docs/model.md §3) and the agents' dynamics.

All functions work on a batch of directed in-links ``j → i`` at once, so one
agent (its own in-links) and a whole team (every link) run the same code.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

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
    out = np.zeros((n, relative.shape[1]))
    np.add.at(out, receivers, terms)
    return -epsilon * out


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
    out = np.zeros((n, relative.shape[1]))
    np.add.at(out, receivers, terms)
    return -epsilon * out


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
