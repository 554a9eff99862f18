"""Scenario generators for teams of any size (tests, benchmarks, sweeps)."""

from __future__ import annotations

from collections.abc import Callable
from itertools import combinations
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from formation.scenario import Scenario, load_dict

IntArray = npt.NDArray[np.intp]


def henneberg_team(
    n: int, spacing_m: float = 1.0, seed: int = 0, redundancy: float = 0.0, **overrides: Any
) -> Scenario:
    """``n`` agents on a perturbed square grid joined by a Henneberg (vertex addition) construction.

    Agent ``k ≥ 3`` is linked to its two nearest earlier agents, so the graph has
    ``2n − 3`` edges and is minimally rigid in the plane (generic positions);
    ``redundancy`` adds that fraction of ``2n − 3`` spare edges between agents at most
    ``1.5 · spacing_m`` apart. The gain is set to ``0.9 / max_degree`` so the scenario
    is always stable.
    """
    side = int(np.ceil(np.sqrt(n)))
    rng = np.random.default_rng(seed)
    grid = np.array([(c, r) for r in range(side) for c in range(side)][:n], dtype=float) * spacing_m
    pts = grid + rng.uniform(-0.15, 0.15, size=grid.shape) * spacing_m
    edges = (
        [[a + 1, b + 1] for a, b in _vertex_addition(pts, 2, lambda k, near: np.sort(near))]
        if n >= 2
        else []
    )
    if redundancy > 0.0:
        edges += _spare_edges(pts, edges, redundancy, 1.5 * spacing_m, rng)
    degree = np.bincount(np.array(edges).ravel(), minlength=n + 1) if edges else np.zeros(1, int)
    data: dict[str, Any] = {
        "name": f"henneberg{n}",
        "epochs": 100,
        "agents": [{"id": i + 1, "offset": [float(v) for v in p]} for i, p in enumerate(pts)],
        "edges": edges,
        "control": {"gain": round(0.9 / max(int(degree.max()), 1), 6)},
        "reference": {"kind": "line", "velocity": [0.01, 0.005]},
        "initial": {"spread_m": 0.2 * spacing_m},
    }
    data.update(overrides)
    return load_dict(data, source=f"henneberg_team(n={n})")


def rigid_team(
    n: int,
    dimension: int = 2,
    redundancy: float = 0.0,
    spacing_m: float = 1.0,
    seed: int = 0,
    **overrides: Any,
) -> Scenario:
    """A rigid team of ``n`` agents in the plane or in space, with a chosen share of spare edges.

    Parameters
    ----------
    n : number of agents, at least ``dimension + 1``
    dimension : 2 or 3
    redundancy : spare edges as a fraction of the minimally rigid ``d·n − d(d+1)/2``; 0.1
        adds one edge in ten, each between agents at most ``1.5 · spacing_m`` apart
    spacing_m : grid spacing [m]; the offsets are a square (cubic) grid moved by up to
        ``0.25 · spacing_m`` per coordinate, so they are generic
    seed : the offsets and the spare edges, and the scenario's run seed
    overrides : scenario fields to set (``epochs``, ``links``, ...)

    Notes
    -----
    The first ``d`` agents are all joined; each later agent is joined to ``d`` earlier ones
    (vertex addition), the best-spread ``d`` of its ``2d`` nearest earlier agents (largest
    ``|det|`` of the unit directions), so the team stays well conditioned as it grows. The
    gain is ``0.9 / max_degree``, so the scenario is always stable. Near-linear in ``n``.
    """
    if dimension not in (2, 3):
        raise ValueError(f"dimension = {dimension}: 2 or 3")
    if n < dimension + 1:
        raise ValueError(f"n = {n}: at least dimension + 1 = {dimension + 1} agents")
    if not 0.0 <= redundancy <= 1.0:
        raise ValueError(f"redundancy = {redundancy}: between 0 and 1")
    d = dimension
    rng = np.random.default_rng(seed)
    side = int(np.ceil(n ** (1.0 / d) - 1e-9))
    grid = np.stack(np.meshgrid(*[np.arange(side)] * d, indexing="ij"), axis=-1).reshape(-1, d)
    pts = (grid[:n, ::-1] + rng.uniform(-0.25, 0.25, size=(n, d))) * spacing_m
    edges = _vertex_addition(pts, 2 * d, lambda k, near: near[_best_spread(pts[near] - pts[k])])
    edges += _spare_edges(pts, edges, redundancy, 1.5 * spacing_m, rng)
    return _team_scenario(pts, edges, "rigid_team", redundancy, spacing_m, seed, overrides)


def _team_scenario(
    pts: npt.NDArray[np.float64],
    edges: list[Any],
    generator: str,
    redundancy: float,
    spacing_m: float,
    seed: int,
    overrides: dict[str, Any],
) -> Scenario:
    """The scenario of a team at ``pts`` (n, d) [m] with 0-based ``edges``, stable by its gain."""
    n, d = pts.shape
    arr = np.array(edges, dtype=np.int64) + 1
    degree = np.bincount(arr.ravel(), minlength=n + 1)
    velocity = [0.01, 0.005, 0.0][:d]
    data: dict[str, Any] = {
        "name": f"{'team' if generator == 'rigid_team' else 'geometric'}{n}-{d}d"
        + (f"-r{redundancy:g}" if redundancy else ""),
        "dimension": d,
        "seed": seed,
        "epochs": 100,
        "agents": [
            {"id": i + 1, "offset": [round(float(v), 6) for v in p]} for i, p in enumerate(pts)
        ],
        "edges": arr.tolist(),
        "control": {"gain": round(0.9 / max(int(degree.max()), 1), 6)},
        "reference": {"kind": "line", "velocity": velocity},
        "initial": {"spread_m": 0.2 * spacing_m},
    }
    data.update(overrides)
    source = f"{generator}(n={n}, dimension={d}, redundancy={redundancy:g})"
    return load_dict(data, source=source)


def geometric_team(
    n: int,
    dimension: int = 2,
    redundancy: float = 0.0,
    spacing_m: float = 1.0,
    seed: int = 0,
    **overrides: Any,
) -> Scenario:
    """A rigid team at uniformly random positions, its edges the shortest ones a rigid graph needs.

    The agents are uniform in a square (cube) of ``1.25 n`` cells of side ``spacing_m``, none
    within ``0.3 · spacing_m`` of another, taken in order of distance from a corner; each later agent is joined to its ``d`` nearest earlier
    agents (vertex addition: rigid at generic positions, no choice of spread as in
    :func:`rigid_team`), and ``redundancy`` of that count in spare edges between agents at
    most ``1.5 · spacing_m`` apart. A random geometric graph made rigid; the gain is
    ``0.9 / max_degree``.
    """
    if dimension not in (2, 3):
        raise ValueError(f"dimension = {dimension}: 2 or 3")
    if n < dimension + 1:
        raise ValueError(f"n = {n}: at least dimension + 1 = {dimension + 1} agents")
    if not 0.0 <= redundancy <= 1.0:
        raise ValueError(f"redundancy = {redundancy}: between 0 and 1")
    d = dimension
    rng = np.random.default_rng(seed)
    raw = rng.uniform(0.0, (1.25 * n) ** (1.0 / d), size=(2 * n, d)) * spacing_m
    keep = np.ones(2 * n, dtype=bool)
    for i, j in cKDTree(raw).query_pairs(0.3 * spacing_m, output_type="ndarray").tolist():
        if keep[i] and keep[j]:  # no two agents closer than 0.3 cells: room for their bodies
            keep[max(i, j)] = False
    raw = raw[keep][:n]
    pts = raw[np.argsort(np.linalg.norm(raw, axis=1), kind="stable")]
    edges = _vertex_addition(pts, d, lambda k, near: near)
    edges += _spare_edges(pts, edges, redundancy, 1.5 * spacing_m, rng)
    return _team_scenario(pts, edges, "geometric_team", redundancy, spacing_m, seed, overrides)


def _spare_edges(
    pts: npt.NDArray[np.float64],
    edges: list[Any],
    redundancy: float,
    reach_m: float,
    rng: np.random.Generator,
) -> list[Any]:
    """``redundancy · len(edges)`` new edges, at random among pairs at most ``reach_m`` apart.

    ``edges`` and the result are in the ids the caller uses (0- or 1-based alike): the pairs
    are 0-based, shifted by the smallest id in ``edges``.
    """
    shift = int(np.min(edges))
    have = {(min(a, b) - shift, max(a, b) - shift) for a, b in edges}
    pairs = cKDTree(pts).query_pairs(reach_m, output_type="ndarray")
    spare = [p for p in pairs[rng.permutation(pairs.shape[0])].tolist() if tuple(p) not in have]
    return [[a + shift, b + shift] for a, b in spare[: round(redundancy * len(edges))]]


def _vertex_addition(
    pts: npt.NDArray[np.float64], near: int, choose: Callable[[int, IntArray], IntArray]
) -> list[tuple[int, int]]:
    """0-based edges of vertex addition over the agents at ``pts`` (n, d) [m], in their order.

    The first ``d`` agents are all joined; each later agent ``k`` to the ``d`` agents that
    ``choose(k, nearest)`` takes from its ``near`` nearest earlier ones (closest first):
    rigid at generic positions.
    """
    n, d = pts.shape
    edges = [(i, j) for j in range(d) for i in range(j)]
    tree = cKDTree(pts)
    for k in range(d, n):
        reach = 2 * d
        while True:  # the nearest agents of all, cut to the earlier ones
            _, idx = tree.query(pts[k], k=min(reach, n))
            earlier = idx[idx < k][:near]
            if earlier.shape[0] >= min(near, k) or reach >= n:
                break
            reach *= 4
        edges += [(int(a), k) for a in choose(k, earlier)]
    return edges


def _best_spread(directions: npt.NDArray[np.float64]) -> list[int]:
    """The ``d`` of the given directions (k, d) whose unit vectors span the most volume."""
    d = directions.shape[1]
    unit = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    choices = list(combinations(range(unit.shape[0]), d))
    volume = np.abs(np.linalg.det(unit[np.array(choices)]))
    return list(choices[int(np.argmax(volume))])
