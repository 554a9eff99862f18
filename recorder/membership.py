"""Who was in the team at each epoch, its changes and the transient after each (issue 20).

Read from the true states a recording holds: agent ``i`` is in the team at epoch ``k``
when its state of ``k`` was recorded. A change is an agent lost (its states stop) or
back (they start again). The transient of a change is how many epochs the team's shape
error (docs/model.md §7, over the edges between present agents) takes to get back under
the threshold. Pure numpy.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from recorder.metrics import shape_error

Array = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]
SHAPE_THRESHOLD_M = 0.05  # the sweep's default: a formation is held under this shape error [m]


@dataclass(frozen=True)
class TeamChange:
    """Agent ``agent`` lost (its first epoch missing) or back (its first epoch again)."""

    epoch: int
    agent: int
    what: Literal["lost", "back"]
    transient_epochs: int | None  # epochs until the shape error is under the threshold again


def present(positions: Array) -> Mask:
    """``positions`` (P, n, d) [m], NaN where not recorded → (P, n) in the team."""
    return np.asarray(np.isfinite(positions).all(axis=2), dtype=bool)


def team_shape_error(positions: Array, edges: npt.NDArray[np.int64], offsets: Array) -> Array:
    """RMS over the edges between present agents of ``||(x_i − x_j) − (d0_i − d0_j)||``.

    positions : (P, n, d) [m], NaN where absent; edges : (m, 2) agent ids; offsets : (n, d).
    Returns (P,) [m], NaN at an epoch without a present edge.
    """
    team = present(positions)
    on = team[:, edges[:, 0] - 1] & team[:, edges[:, 1] - 1]  # (P, m)
    return shape_error(np.nan_to_num(positions), edges, offsets, on)


def changes(team: Mask, shape: Array, threshold_m: float = SHAPE_THRESHOLD_M) -> list[TeamChange]:
    """Every change of ``team`` (P, n) after epoch 0, in epoch order, with its transient.

    shape : (P,) the team's shape error [m]; the transient counts epochs from the change
    until it is first under ``threshold_m`` (None if it never is).
    """
    out: list[TeamChange] = []
    flips = np.argwhere(team[1:] != team[:-1])  # (c, 2): epoch - 1, agent row
    for k0, col in flips.tolist():
        k = k0 + 1
        under = np.flatnonzero(shape[k:] < threshold_m)
        what: Literal["lost", "back"] = "back" if team[k, col] else "lost"
        out.append(TeamChange(k, col + 1, what, int(under[0]) if len(under) else None))
    return out


def spans(team: Mask) -> dict[int, list[tuple[int, int]]]:
    """Agent → ``[(first, last), ...]`` epochs it was in the team (``team`` (P, n))."""
    out: dict[int, list[tuple[int, int]]] = {}
    for col in range(team.shape[1]):
        on = np.concatenate(([0], team[:, col].astype(np.int8), [0]))
        edges = np.flatnonzero(np.diff(on))
        out[col + 1] = [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2], strict=True)]
    return out


__all__ = ["SHAPE_THRESHOLD_M", "TeamChange", "changes", "present", "spans", "team_shape_error"]
