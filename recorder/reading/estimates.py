"""The leader's estimates of a recording as the arrays of :class:`analysis.RunData`.

An estimate of 10,000 agents holds 10,000 positions and covariances and 20,000 edges; they
are stacked as arrays once (:func:`estimate_arrays`), which the trust gate checks and the
reader keeps, not set one agent at a time.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import chain
from typing import Any

import numpy as np
import numpy.typing as npt

from analysis import edge_mask
from formation.scenario import Scenario
from recorder.reading.value_checks import rows_of

Array = npt.NDArray[np.float64]
Ints = npt.NDArray[np.int64]


@dataclass(frozen=True)
class EstimateArrays:
    """A leader's estimate as arrays: the rows of ``positions`` that are given and those
    positions (p, d) [m], the rows of ``covariances`` that are given and those blocks
    (c, d, d) [m²], the id pairs of ``tree`` (t, 2) and of ``healthy`` (h, 2)."""

    with_position: Ints
    positions: Array
    with_covariance: Ints
    covariances: Array
    tree: Ints
    healthy: Ints


# the last estimate whose arrays were made, and them: one tuple, read once (threads share it)
_last: list[tuple[Any, EstimateArrays | None]] = [(None, None)]


def estimate_arrays(msg: Any, d: int) -> EstimateArrays | None:
    """``msg``'s lists as arrays, or None unless every given position has ``d`` components
    and every covariance is d×d (then the gate names the one at fault). Made once for the
    estimate the trust gate checks and the reader then keeps (the last one's are remembered)."""
    last = _last[0]
    if last[0] is msg:
        return last[1]
    positions = _given(msg.positions, (d,))
    covariances = _given(msg.covariances, (d, d))
    tree, healthy = _pairs(msg.tree), _pairs(msg.healthy)
    out = None
    if positions and covariances and tree is not None and healthy is not None:
        out = EstimateArrays(*positions, *covariances, tree, healthy)
    _last[0] = (msg, out)
    return out


def _given(values: list[Any], shape: tuple[int, ...]) -> tuple[Ints, Array] | None:
    """The rows of ``values`` that are not None, and those values as one array of rows of
    ``shape``; None if one is not of ``shape``."""
    given = [i for i, v in enumerate(values) if v is not None]
    if not given:
        return np.zeros(0, dtype=np.int64), np.zeros((0, *shape))
    rows = rows_of(values if len(given) == len(values) else [values[i] for i in given], shape)
    if rows is None:  # ragged, or not numbers
        return None
    return np.array(given, dtype=np.int64), rows


def _pairs(pairs: list[tuple[int, int]]) -> Ints | None:
    """Id pairs (the models' type: tuples of two ints) as a (k, 2) array; None past 63 bits."""
    try:
        return np.fromiter(chain.from_iterable(pairs), np.int64, 2 * len(pairs)).reshape(-1, 2)
    except (OverflowError, ValueError, TypeError):
        return None


def estimates(
    scenario: Scenario,
    ests: dict[int, Any],
    count: int,
    arrays: dict[int, EstimateArrays | None] | None = None,
) -> dict[str, Any]:
    """``estimates``, ``estimate_cov``, ``observable``, ``estimated``, ``healthy``, ``tree``,
    ``components``, ``rigidity_rank`` and ``rigid`` of :class:`analysis.RunData` for epochs
    ``0..count − 1`` from the trusted estimates ``ests`` (models or structs) by epoch, and
    their :func:`estimate_arrays` by epoch where already made."""
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
    arrays = arrays or {}
    for k, e in ests.items():
        a = arrays.get(k) or estimate_arrays(e, d)
        if (
            not 0 <= k < count or a is None
        ):  # None: not of the scenario's shapes, which the gate refuses
            continue
        out["estimated"][k] = True
        agents = min(len(e.positions), len(e.covariances), n)  # the two zipped, within the team
        keep = a.with_position < agents
        out["estimates"][k, a.with_position[keep]] = a.positions[keep]
        keep = a.with_covariance < agents
        out["estimate_cov"][k, a.with_covariance[keep]] = a.covariances[keep]
        out["observable"][k, : len(e.observable[:n])] = e.observable[:n]
        out["healthy"][k] = edge_mask(scenario.edge_array, a.healthy)
        out["tree"][k] = edge_mask(scenario.edge_array, a.tree)
        out["components"][k], out["rigidity_rank"][k] = e.components, e.rigidity_rank
        out["rigid"][k] = e.rigid
    return out


__all__ = ["EstimateArrays", "estimate_arrays", "estimates"]
