"""The formation graph as arrays: edge and position checks, connectivity, degree (docs/model.md §1).

Agents have ids ``1..n``; an edge list is an ``(m, 2)`` integer array of ids and
row ``i − 1`` of a positions array is agent ``i``. These functions live in the
vocabulary layer because the scenario loader must check that a shape is
connected (and rigid: :mod:`formation.rigidity`); the leader uses the edge checks
for its own inputs.
"""

from __future__ import annotations

import operator

import numpy as np
import numpy.typing as npt
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from formation.errors import AgentIdError, GraphInputError, ShapeError

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


def _check_positive(value: int, name: str, integer: str, least: str) -> int:
    """``value`` as an ``int`` after checking that it is an integer ``>= 1``; the error expects
    ``integer`` (not an integer) or ``least`` (below 1)."""
    try:
        count = operator.index(value)
    except TypeError:
        raise GraphInputError(f"{name} = {value!r}", integer) from None
    if count < 1:
        raise GraphInputError(f"{name} = {count}", least)
    return count


def check_agent_count(n: int, name: str = "n") -> int:
    """Return ``n`` as an ``int`` after checking that it is an integer ``>= 1``."""
    return _check_positive(n, name, "an integer number of agents", "at least 1 agent")


def check_dimension(d: int, name: str = "d") -> int:
    """Return ``d`` as an ``int`` after checking that it is an integer ``>= 1``."""
    return _check_positive(d, name, "an integer dimension", "a dimension of at least 1")


def as_edge_array(n: int, edges: npt.ArrayLike, name: str = "edges") -> IntArray:
    """Check an edge list and return it as an ``(m, 2)`` int64 array of agent ids.

    Parameters
    ----------
    n : int
        Number of agents; ids run ``1..n``.
    edges : (m, 2) array_like of int
        One row ``(i, j)`` per edge. An empty sequence is ``m = 0``.
    name : str
        Name used in error messages.

    Raises
    ------
    ShapeError
        If ``edges`` is not ``(m, 2)``.
    AgentIdError
        If an id is outside ``1..n`` or an edge joins an agent to itself.
    GraphInputError
        If the ids are not integers.
    """
    arr = np.asarray(edges)
    if arr.size == 0 and (arr.ndim == 1 or arr.shape[-1] == 2):
        return np.empty((0, 2), dtype=np.int64)  # `[]` is float64 to numpy: no edges
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ShapeError(name, arr.shape, "(m, 2)")
    if arr.dtype == np.bool_ or not np.issubdtype(arr.dtype, np.integer):
        raise GraphInputError(f"{name} has dtype {arr.dtype}", "integer agent ids")
    out = arr.astype(np.int64, copy=False)
    bad = np.flatnonzero(((out < 1) | (out > n)).any(axis=1))
    if bad.size:
        k = int(bad[0])
        i, j = (int(v) for v in out[k])
        agent = i if not 1 <= i <= n else j
        raise AgentIdError(f"{name}[{k}] = ({i}, {j}) names agent {agent}", f"ids in 1..{n}")
    loops = np.flatnonzero(out[:, 0] == out[:, 1])
    if loops.size:
        k = int(loops[0])
        i = int(out[k, 0])
        raise AgentIdError(f"{name}[{k}] = ({i}, {i}) is a self-loop", "two different agents")
    return out


def as_edge_mask(mask: npt.ArrayLike | None, m: int, name: str = "mask") -> BoolArray:
    """Check a boolean mask over ``m`` edges (``None`` = every edge) and return it as bools."""
    if mask is None:
        return np.ones(m, dtype=np.bool_)
    arr = np.asarray(mask)
    if arr.shape != (m,):
        raise ShapeError(name, arr.shape, f"({m},)")
    integral = np.issubdtype(arr.dtype, np.integer) and bool(np.isin(arr, (0, 1)).all())
    if arr.dtype != np.bool_ and arr.size and not integral:
        raise GraphInputError(f"{name} has dtype {arr.dtype}", "booleans (or 0/1)")
    return arr.astype(np.bool_, copy=False)


def component_labels(n: int, edges: npt.ArrayLike, mask: npt.ArrayLike | None = None) -> IntArray:
    """Connected components of the undirected graph on agents ``1..n``.

    Parameters
    ----------
    n : int
        Number of agents.
    edges : (m, 2) array_like of int
        Agent ids ``1..n``.
    mask : (m,) array_like of bool, optional
        Edges to keep; default every edge.

    Returns
    -------
    labels : (n,) int64 array
        ``labels[i − 1]`` is agent ``i``'s component, numbered ``0, 1, …`` in the
        order of each component's smallest agent id (so agent 1 is in component 0).
    """
    count = check_agent_count(n)
    e = as_edge_array(count, edges)
    keep = as_edge_mask(mask, e.shape[0])
    e = e[keep] - 1
    graph = coo_matrix(
        (np.ones(e.shape[0], dtype=np.int8), (e[:, 0], e[:, 1])), shape=(count, count)
    ).tocsr()
    raw: IntArray = connected_components(graph, directed=False)[1].astype(np.int64)
    # scipy numbers components by discovery; renumber by smallest member for a stable contract
    _, first = np.unique(raw, return_index=True)
    rename = np.empty(first.size, dtype=np.int64)
    rename[np.argsort(first, kind="stable")] = np.arange(first.size)
    labels: IntArray = rename[raw]
    return labels


def is_connected(n: int, edges: npt.ArrayLike) -> bool:
    """Whether the undirected graph on agents ``1..n`` is connected (one agent: yes)."""
    return bool(component_labels(n, edges).max() == 0)


def max_degree(n: int, edges: npt.ArrayLike) -> int:
    """Largest number of distinct neighbours of any agent (Δ_max of docs/model.md §3); 0 if no edges."""
    count = check_agent_count(n)
    e = as_edge_array(count, edges)
    if e.shape[0] == 0:
        return 0
    pairs = np.unique(np.sort(e, axis=1), axis=0)  # parallel edges are one neighbour
    return int(np.bincount(pairs.ravel(), minlength=count + 1).max())


def as_positions(positions: npt.ArrayLike, name: str = "positions") -> FloatArray:
    """Check a ``(n, d)`` array of finite positions (row ``i − 1`` = agent ``i``)."""
    arr = np.asarray(positions, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise ShapeError(name, arr.shape, "(n, d) with n >= 1 and d >= 1")
    if not np.isfinite(arr).all():
        row = int(np.flatnonzero(~np.isfinite(arr).all(axis=1))[0])
        raise GraphInputError(f"{name}[{row}] is not finite", "finite coordinates")
    return arr
