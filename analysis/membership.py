"""Who was in the team at each epoch, its changes and the transient after each.

Read from the true states a recording holds: agent ``i`` is in the team at epoch ``k``
when its state of ``k`` was recorded. A change is an agent lost (its states stop) or
back (they start again); one the scenario's events planned is named by its action and
epoch instead (a ``leave`` or ``crash`` at ``c`` publishes ``x[c]`` last, so its states stop
at ``c + 1``; a ``join`` or ``restart`` at ``r`` publishes from ``x[r]``). The transient
of a change is how many epochs the team's shape error (docs/model.md §7, over the edges
between present agents) takes to get back under the threshold. Pure numpy.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from analysis.metrics import formation_error, shape_error

Array = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]
SHAPE_THRESHOLD_M = 0.05  # the sweep's default: a formation is held under this shape error [m]


Action = Literal["lost", "back", "leave", "crash", "join", "restart"]


@dataclass(frozen=True)
class TeamChange:
    """Agent ``agent`` lost (its first epoch missing) or back (its first epoch again), or
    the scenario's ``leave``, ``crash``, ``join`` or ``restart`` at its own epoch."""

    epoch: int
    agent: int
    what: Action
    transient_epochs: int | None  # epochs until the shape error is under the threshold again


def present(positions: Array) -> Mask:
    """``positions`` (..., n, d) [m], NaN where not recorded → (..., n) in the team.

    The one test of who is in a run's team: a state of the epoch recorded (the simulator's
    record marks the same, ``Membership.published``).
    """
    return np.asarray(np.isfinite(positions).all(axis=-1), dtype=bool)


def edge_mask(
    edges: npt.NDArray[np.int64], pairs: Sequence[tuple[int, int]] | npt.NDArray[np.int64]
) -> Mask:
    """Which of ``edges`` (m, 2) appear, in either order, in ``pairs`` (a leader's healthy
    edges or tree: a list of pairs or a (k, 2) array)."""
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    try:  # as codes: a leader's estimate of 10,000 agents lists 20,000 pairs an epoch
        ends: npt.NDArray[np.int64] | None = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    except (OverflowError, ValueError, TypeError):
        ends = None
    if ends is not None and len(ends) != len(pairs):
        ends = None  # not pairs
    base = 0 if ends is None else int(max(edges.max(initial=0), ends.max(initial=0))) + 1
    if ends is None or (ends < 0).any() or (edges < 0).any() or base > 2**31:
        wanted = {(min(a, b), max(a, b)) for a, b in pairs}
        return np.array([(int(i), int(j)) in wanted for i, j in edges], dtype=bool)
    return _among(edges[:, 0] * base + edges[:, 1], ends.min(axis=1) * base + ends.max(axis=1))


def _among(values: npt.NDArray[np.int64], pool: npt.NDArray[np.int64]) -> Mask:
    """``np.isin(values, pool)`` by one sort and a binary search (no hashing of both)."""
    if not len(pool):
        return np.zeros(len(values), dtype=bool)
    pool = np.sort(pool)
    at = np.minimum(np.searchsorted(pool, values), len(pool) - 1)
    return np.asarray(pool[at] == values, dtype=bool)


def team_edges(team: Mask, edges: npt.NDArray[np.int64]) -> Mask:
    """(..., m) both ends of each edge in the team; ``team`` (..., n), ``edges`` (m, 2) agent ids."""
    return np.asarray(team[..., edges[:, 0] - 1] & team[..., edges[:, 1] - 1], dtype=bool)


def team_shape_error(
    positions: Array, edges: npt.NDArray[np.int64], offsets: Array, team: Mask | None = None
) -> Array:
    """RMS over the edges between agents in the team of ``||(x_i − x_j) − (d0_i − d0_j)||``.

    positions : (..., n, d) [m], NaN where absent; edges : (m, 2) agent ids; offsets : (n, d);
    team : (..., n) in the team, broadcast against ``positions``' leading axes (None: a state
    recorded, :func:`present`). Returns (...) [m], NaN where no edge is in the team.
    """
    on = team_edges(present(positions) if team is None else team, edges)
    return shape_error(np.nan_to_num(positions), edges, offsets, on)


def team_formation_error(
    positions: Array, edges: npt.NDArray[np.int64], weights: Array, team: Mask | None = None
) -> Array:
    """RMS over the edges between agents in the team of ``||x_i − x_j|| − C_ij``; as
    :func:`team_shape_error` with ``weights`` (m,) ``C_ij`` [m]."""
    on = team_edges(present(positions) if team is None else team, edges)
    return formation_error(np.nan_to_num(positions), edges, weights, on)


def team_errors(
    positions: Array,
    team: Mask,
    formation: Array,
    shape: Array,
    edges: npt.NDArray[np.int64],
    weights: Array,
    offsets: Array,
) -> tuple[Array, Array]:
    """Formation and shape error [m] of the team: over every edge where every agent is in
    it, else over the edges between the agents in it (docs/model.md §7).

    A body out of the team (left, crashed, not yet joined) stands where it was while the
    team moves on, so its edges would judge the team on it.

    Parameters
    ----------
    positions : (..., n, d) true positions [m], NaN allowed where out of the team
    team : (..., n) in the team, broadcast against ``positions``' leading axes
    formation, shape : (...) the run's errors over every edge [m]
    edges : (m, 2) agent ids; weights : (m,) ``C_ij`` [m]; offsets : (n, d) [m]

    Returns
    -------
    formation, shape : (...) [m], NaN where no edge is in the team
    """
    team = np.broadcast_to(team, positions.shape[:-1])
    everyone = team.all(axis=-1)
    if everyone.all():  # nobody out: the run's own errors, untouched
        return formation, shape
    lead = positions.shape[:-2]
    x = positions.reshape(-1, *positions.shape[-2:])
    flat = team.reshape(-1, team.shape[-1])
    partial = (
        team_formation_error(x, edges, weights, flat).reshape(lead),
        team_shape_error(x, edges, offsets, flat).reshape(lead),
    )
    return np.where(everyone, formation, partial[0]), np.where(everyone, shape, partial[1])


def changes(
    team: Mask,
    shape: Array,
    threshold_m: float = SHAPE_THRESHOLD_M,
    events: Sequence[tuple[int, int, str]] = (),
) -> list[TeamChange]:
    """Every change of ``team`` (P, n) after epoch 0, in epoch order, with its transient.

    shape : (P,) the team's shape error [m]; the transient counts epochs from the change
    until it is first under ``threshold_m`` (None if it never is). events : the
    scenario's ``(epoch, agent, action)``; a change they explain takes their name and epoch.
    """
    planned = {(agent, epoch): action for epoch, agent, action in events}
    out: list[TeamChange] = []
    flips = np.argwhere(team[1:] != team[:-1])  # (c, 2): epoch - 1, agent row
    for k0, col in flips.tolist():
        k, agent = k0 + 1, col + 1
        what, k = _named(planned, agent, k, back=bool(team[k, col]))
        under = np.flatnonzero(shape[k:] < threshold_m)
        out.append(TeamChange(k, agent, what, int(under[0]) if len(under) else None))
    return sorted(out, key=lambda c: (c.epoch, c.agent))  # a planned leave or crash moved back


def _named(
    planned: dict[tuple[int, int], str], agent: int, k: int, back: bool
) -> tuple[Action, int]:
    """A change of ``agent`` seen at ``k`` as the scenario's event that explains it, if one does."""
    actions: dict[str, Action] = (
        {"join": "join", "restart": "restart"} if back else {"leave": "leave", "crash": "crash"}
    )
    for at in (k,) if back else (k - 1, k):  # a leave's or crash's last state is its own epoch's
        action = actions.get(planned.get((agent, at), ""))
        if action is not None:
            return action, at
    return ("back" if back else "lost"), k


def spans(team: Mask) -> dict[int, list[tuple[int, int]]]:
    """Agent → ``[(first, last), ...]`` epochs it was in the team (``team`` (P, n))."""
    out: dict[int, list[tuple[int, int]]] = {}
    for col in range(team.shape[1]):
        on = np.concatenate(([0], team[:, col].astype(np.int8), [0]))
        edges = np.flatnonzero(np.diff(on))
        out[col + 1] = [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2], strict=True)]
    return out


def errors_of_team(
    positions: Array,
    team: Mask,
    edges: npt.NDArray[np.int64],
    weights: Array,
    offsets: Array,
) -> tuple[Array, Array]:
    """:func:`team_errors` of ``positions`` from nothing else: the errors over every edge first."""
    return team_errors(
        positions,
        team,
        formation_error(positions, edges, weights),
        shape_error(positions, edges, offsets),
        edges,
        weights,
        offsets,
    )


__all__ = [
    "SHAPE_THRESHOLD_M",
    "Action",
    "TeamChange",
    "changes",
    "edge_mask",
    "errors_of_team",
    "present",
    "spans",
    "team_edges",
    "team_errors",
    "team_formation_error",
    "team_shape_error",
]
