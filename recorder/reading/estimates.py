"""The leader's estimates of a recording as the arrays of :class:`analysis.RunData`.

An estimate of 10,000 agents holds 10,000 positions and covariances and 20,000 edges; they
are stacked as arrays, not set one agent at a time.
"""

from __future__ import annotations

from itertools import chain
from typing import Any

import numpy as np
import numpy.typing as npt

from analysis import edge_mask
from formation.scenario import Scenario


def _stacked(values: list[Any], shape: tuple[int, ...]) -> tuple[list[int], npt.NDArray[Any]]:
    """The indices of the given (not None) ``values`` and those values as one array."""
    given = [i for i, v in enumerate(values) if v is not None]
    rows = [values[i] for i in given]
    for _ in shape[1:]:
        rows = list(chain.from_iterable(rows))
    size = len(given) * int(np.prod(shape))
    flat = np.fromiter(chain.from_iterable(rows), float, size)  # the gate checked the shapes
    return given, flat.reshape(len(given), *shape)


def estimates(scenario: Scenario, ests: dict[int, Any], count: int) -> dict[str, Any]:
    """``estimates``, ``estimate_cov``, ``observable``, ``estimated``, ``healthy``, ``tree``,
    ``components``, ``rigidity_rank`` and ``rigid`` of :class:`analysis.RunData` for epochs
    ``0..count − 1`` from the trusted estimates ``ests`` (models or structs) by epoch."""
    n, d, m = scenario.n, scenario.dimension, len(scenario.edges)
    out: dict[str, Any] = {
        "estimates": np.full((count, n, d), np.nan),
        "estimate_cov": np.full((count, n, d, d), np.nan),
        "observable": np.zeros((count, n), dtype=bool),
        "estimated": np.zeros(count, dtype=bool),
        "healthy": np.zeros((count, m), dtype=bool),
        "tree": np.zeros((count, m), dtype=bool),
        "components": np.full(count, -1, dtype=np.int64),
        "rigidity_rank": np.full(count, -1, dtype=np.int64),
        "rigid": np.full(count, -1, dtype=np.int64),
    }
    for k, e in ests.items():
        if not 0 <= k < count:
            continue
        out["estimated"][k] = True
        agents = min(len(e.positions), len(e.covariances), n)  # the two zipped, within the team
        at, rows = _stacked(e.positions[:agents], (d,))
        out["estimates"][k, at] = rows
        at, rows = _stacked(e.covariances[:agents], (d, d))
        out["estimate_cov"][k, at] = rows
        out["observable"][k, : len(e.observable[:n])] = e.observable[:n]
        out["healthy"][k] = edge_mask(scenario.edge_array, list(e.healthy))
        out["tree"][k] = edge_mask(scenario.edge_array, list(e.tree))
        out["components"][k], out["rigidity_rank"][k] = e.components, e.rigidity_rank
        out["rigid"][k] = e.rigid
    return out


__all__ = ["estimates"]
