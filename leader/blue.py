"""Best linear unbiased estimate of every agent's position from relative measurements (docs/model.md §5).

Measurement on the used edge ``e = (i, j)``::

    z_e = x_i − x_j + ε_e,   ε_e ~ N(0, P_e),   P_e ∈ R^{d×d} SPD

Stacked, ``z = (H ⊗ I_d) x + ε`` with ``H`` the oriented incidence matrix. With
the reference ``r`` known (``x_r``), the columns split into ``r`` and the rest
``b`` and the weighted least-squares (Gauss–Markov) estimate is::

    A = H_bᵀ P⁻¹ H_b                    (grounded weighted Laplacian, block form)
    x̂_b = A⁻¹ H_bᵀ P⁻¹ (z − H_r x_r),   Cov(x̂_b) = A⁻¹

``A`` is invertible exactly on the agents joined to ``r`` by used edges, so the
estimate is computed on the reference's component and the other agents are
reported unobservable. ``A`` is assembled sparse and never inverted densely;
the solver follows the structure of the used graph:

* **tree** (the component has ``size − 1`` distinct links; repeated
  measurements of one pair, such as both directions of a link, are first fused
  into one by adding their information): ``H_b`` is square and
  invertible, so ``x̂`` is the path sum of the signed measurements from ``r``
  and the covariance of agent ``v`` is the sum of ``P_e`` along its path
  (independent noises add). Both by pointer jumping over the BFS tree, ``O(n log depth)``.
* **diagonal** ``P_e`` (scalar-times-identity or any diagonal): the ``d``
  coordinates decouple, ``A = ⊕_k L_k`` with ``L_k`` the ``n_b × n_b`` grounded
  Laplacian weighted by ``1 / P_e[k, k]``; coordinates with equal weights share
  one matrix (one factorisation for all ``d`` when ``P_e = σ_e² I``).
* **full** ``P_e``: the ``(n_b d) × (n_b d)`` block system with blocks ``±P_e⁻¹``.

A cyclic system (``leader.laplacian``) is solved by sparse LU (SuperLU,
minimum-degree ordering; the matrix is SPD so no pivoting is needed) when the
structure promises little fill, else by conjugate gradients with a (block-)Jacobi preconditioner to a
relative residual of 1e-12. The promise is judged from the graph: the squared
envelope of a reverse Cuthill–McKee ordering (an upper bound on a direct
factorisation's work) against ``8 × BFS depth`` CG iterations (measured on
formation-like and expander graphs, bench/bench_leader.py). Planar formation
graphs factor cheaply; expanders fill in badly but are well conditioned.

Covariance blocks on a cyclic graph are the ``d × d`` diagonal blocks of
``A⁻¹``: the LU factorisation is solved against blocks of identity columns and
only the diagonal blocks are kept, ``O(n_b · nnz(LU))`` time and
``O(n_b · 256)`` extra memory. This is exact but not cheap at scale (seconds at
10,000 agents; see the benchmark); a selected inversion (Takahashi) would be
the next step. Pass ``covariances=False`` to skip it.
"""

from __future__ import annotations

import operator
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt
from scipy.sparse import coo_array, csr_array
from scipy.sparse.csgraph import breadth_first_order, connected_components

from formation.graph import (
    AgentIdError,
    GraphInputError,
    ShapeError,
    as_edge_array,
    as_edge_mask,
    check_agent_count,
)
from leader.laplacian import _choose_method, _System

__all__ = ["BlueResult", "CovarianceError", "Solver", "blue", "nees"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]
Solver = Literal["auto", "tree", "direct", "cg"]

SYMMETRY_RTOL = 1e-10
"""A covariance counts as symmetric when ``|P − Pᵀ| ≤ 1e-10 · max|P|``."""


class CovarianceError(GraphInputError):
    """A measurement covariance that is not symmetric positive definite."""


@dataclass(frozen=True, eq=False)
class BlueResult:
    """The BLUE of one epoch (docs/model.md §5).

    Attributes
    ----------
    positions : (n, d) float64 array [m]
        Row ``i − 1`` is agent ``i``'s estimate; the reference's row is ``x_ref``;
        NaN rows for unobservable agents.
    covariances : (n, d, d) float64 array [m²] or None
        Estimation error covariance blocks ``Cov(x̂_i)``; zero for the reference,
        NaN for unobservable agents; ``None`` when not requested.
    observable : (n,) bool array
        Agents joined to the reference by used edges (the reference included).
    solver : str
        How the system was solved: ``"tree"``, ``"direct"``, ``"cg"``, or
        ``"none"`` when no agent besides the reference is observable.
    """

    positions: FloatArray
    covariances: FloatArray | None
    observable: BoolArray
    solver: str


def blue(
    n: int,
    d: int,
    edges: npt.ArrayLike,
    z: npt.ArrayLike,
    cov: npt.ArrayLike,
    ref: int,
    x_ref: npt.ArrayLike,
    use: npt.ArrayLike | None = None,
    *,
    covariances: bool = True,
    solver: Solver = "auto",
) -> BlueResult:
    """BLUE of all agents' positions relative to the reference (docs/model.md §5).

    Parameters
    ----------
    n : int
        Number of agents; ids ``1..n``.
    d : int
        Dimension of the positions.
    edges : (m, 2) array_like of int
        Oriented measurement edges ``(i, j)``; parallel edges (e.g. both
        directions of one link) are separate measurements.
    z : (m, d) array_like [m]
        ``z[e] = x_i − x_j + noise`` for ``edges[e] = (i, j)``.
    cov : (m, d, d) array_like [m²]
        Noise covariance of each measurement, symmetric positive definite.
    ref : int
        The reference agent.
    x_ref : (d,) array_like [m]
        The reference's known position.
    use : (m,) array_like of bool, optional
        Measurements to use (e.g. the Kruskal tree or every healthy edge);
        default all.
    covariances : bool
        Whether to compute the covariance blocks (cheap on a tree, seconds on a
        large graph with many cycles).
    solver : {"auto", "tree", "direct", "cg"}
        ``"auto"`` chooses by structure (module docstring). ``"tree"`` needs the
        reference's component to be a tree; ``"direct"`` and ``"cg"`` force the
        cyclic solvers (``"cg"`` still factorises for covariance blocks).

    Returns
    -------
    BlueResult

    Raises
    ------
    GraphInputError
        Wrong shapes or dtypes, agent ids outside ``1..n``, non-finite values
        (``ShapeError``, ``AgentIdError`` are subclasses; all are ``ValueError``).
    CovarianceError
        A covariance that is not symmetric positive definite.
    """
    count = check_agent_count(n)
    dim = _check_dimension(d)
    e = as_edge_array(count, edges)
    m = e.shape[0]
    zz = _as_finite(z, "z", (m, dim), "measurements")
    pp = _as_finite(cov, "cov", (m, dim, dim), "covariances")
    r = _check_ref(ref, count)
    xr = _as_finite(x_ref, "x_ref", (dim,), "coordinates")
    used = as_edge_mask(use, m, "use")
    if solver not in ("auto", "tree", "direct", "cg"):
        raise GraphInputError(f"solver = {solver!r}", "'auto', 'tree', 'direct' or 'cg'")
    diagonal = _check_covariances(pp)

    idx = np.flatnonzero(used)
    ue = e[idx] - 1  # 0-based agents
    graph = _adjacency(count, ue)
    labels: IntArray = connected_components(graph, directed=False)[1]
    observable = labels == labels[r]
    inside = idx[observable[ue[:, 0]]]  # used edges within the reference's component
    size = int(np.count_nonzero(observable))

    positions = np.full((count, dim), np.nan)
    positions[r] = xr
    blocks = np.full((count, dim, dim), np.nan) if covariances else None
    if blocks is not None:
        blocks[r] = 0.0
    if size == 1:
        return BlueResult(positions, blocks, observable, "none")

    fe, fz, fp = _fuse_parallel(count, e[inside] - 1, zz[inside], pp[inside])
    is_tree = fe.shape[0] == size - 1
    if solver == "tree" and not is_tree:
        raise GraphInputError(
            f"solver = 'tree' but the reference's component has {size} agents and "
            f"{fe.shape[0]} distinct used links",
            f"{size - 1} (a tree)",
        )
    if solver == "tree" or (solver == "auto" and is_tree):
        _tree_solve(graph, fe, fz, fp, r, xr, positions, blocks)
        return BlueResult(positions, blocks, observable, "tree")

    system = _System(count, r, observable, fe, fz, fp, xr, diagonal)
    method = solver if solver != "auto" else _choose_method(system, graph, r)
    system.solve(method, positions, blocks)
    return BlueResult(positions, blocks, observable, system.method)


def nees(result: BlueResult, x_true: npt.ArrayLike) -> FloatArray:
    """Normalised estimation error squared per agent (docs/model.md §5, "Consistency").

    ``NEES_i = (x̂_i − x_i)ᵀ Cov(x̂_i)⁻¹ (x̂_i − x_i)``; for an honest estimator with
    Gaussian noise it is χ²-distributed with ``d`` degrees of freedom, mean ``d``.

    Parameters
    ----------
    result : BlueResult
        An estimate computed with ``covariances=True``.
    x_true : (n, d) array_like [m]
        True positions, row ``i − 1`` = agent ``i``.

    Returns
    -------
    (n,) float64 array
        NaN for unobservable agents and for the reference (its covariance is zero).
    """
    if result.covariances is None:
        raise GraphInputError("result has no covariances", "a result of blue(covariances=True)")
    shape = result.positions.shape
    x = np.asarray(x_true, dtype=np.float64)
    if x.shape != shape:
        raise ShapeError("x_true", x.shape, f"{shape}")
    out = np.full(shape[0], np.nan)
    err = result.positions - x
    has = result.observable & (np.abs(result.covariances).sum(axis=(1, 2)) > 0)
    solved = np.linalg.solve(result.covariances[has], err[has][..., None])[..., 0]
    out[has] = np.einsum("ij,ij->i", err[has], solved)
    return out


# --------------------------------------------------------------------------- input checks


def _check_dimension(d: int) -> int:
    try:
        dim = operator.index(d)
    except TypeError:
        raise GraphInputError(f"d = {d!r}", "an integer dimension") from None
    if dim < 1:
        raise GraphInputError(f"d = {dim}", "a dimension of at least 1")
    return dim


def _check_ref(ref: int, n: int) -> int:
    try:
        r = operator.index(ref)
    except TypeError:
        raise AgentIdError(f"ref = {ref!r}", f"an agent id in 1..{n}") from None
    if not 1 <= r <= n:
        raise AgentIdError(f"ref = {r}", f"an agent id in 1..{n}")
    return r - 1


def _as_finite(value: npt.ArrayLike, name: str, shape: tuple[int, ...], what: str) -> FloatArray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != shape:
        raise ShapeError(name, arr.shape, str(shape))
    if not np.isfinite(arr).all():
        if arr.ndim == 1:
            raise GraphInputError(f"{name} is not finite", f"finite {what}")
        k = int(np.flatnonzero(~np.isfinite(arr.reshape(shape[0], -1)).all(axis=1))[0])
        raise GraphInputError(f"{name}[{k}] is not finite", f"finite {what}")
    return arr


def _check_covariances(p: FloatArray) -> bool:
    """Check every ``P_e`` is symmetric positive definite; return whether all are diagonal."""
    m, d, _ = p.shape
    if m == 0:
        return True
    iu, ju = np.triu_indices(d, 1)
    upper, lower = p[:, iu, ju], p[:, ju, iu]
    scale = np.abs(p).max(axis=(1, 2))
    asym = np.abs(upper - lower).max(axis=1) if iu.size else np.zeros(m)
    bad = np.flatnonzero(asym > SYMMETRY_RTOL * scale)
    if bad.size:
        k = int(bad[0])
        raise CovarianceError(
            f"cov[{k}] is not symmetric (largest |P − Pᵀ| entry {asym[k]:.3g})",
            "a symmetric positive definite matrix",
        )
    diag = p[:, np.arange(d), np.arange(d)]
    diagonal = not (iu.size and np.any(upper != 0.0))
    if diagonal:
        ok = diag > 0.0
        if not ok.all():
            k = int(np.flatnonzero(~ok.all(axis=1))[0])
            raise _not_spd(k, float(diag[k].min()))
        return True
    try:
        np.linalg.cholesky(p)
    except np.linalg.LinAlgError:
        low = np.linalg.eigvalsh(p)[:, 0]
        k = int(np.flatnonzero(~(low > 0.0))[0])
        raise _not_spd(k, float(low[k])) from None
    return False


def _not_spd(k: int, smallest: float) -> CovarianceError:
    return CovarianceError(
        f"cov[{k}] has smallest eigenvalue {smallest:.3g}", "a symmetric positive definite matrix"
    )


# --------------------------------------------------------------------------- tree


def _fuse_parallel(
    n: int, e: IntArray, z: FloatArray, p: FloatArray
) -> tuple[IntArray, FloatArray, FloatArray]:
    """Merge measurements of the same pair (e.g. both directions of a link) into one.

    Two independent measurements of ``x_i − x_j`` are one with information
    ``Σ P_k⁻¹`` and value ``(Σ P_k⁻¹)⁻¹ Σ P_k⁻¹ z_k``; the BLUE is unchanged and a
    tree measured in both directions is still solved as a tree. Edges are 0-based.
    """
    lo, hi = np.minimum(e[:, 0], e[:, 1]), np.maximum(e[:, 0], e[:, 1])
    keys, group = np.unique(lo * n + hi, return_inverse=True)
    if keys.size == e.shape[0]:
        return e, z, p
    d = z.shape[1]
    oriented = np.where((e[:, 0] == lo)[:, None], z, -z)  # measures x_lo − x_hi
    info = np.linalg.inv(p)
    info_sum = np.zeros((keys.size, d, d))
    np.add.at(info_sum, group, info)
    weighted = np.zeros((keys.size, d))
    np.add.at(weighted, group, np.einsum("eab,eb->ea", info, oriented))
    fused_p = np.linalg.inv(info_sum)
    fused_p = 0.5 * (fused_p + fused_p.transpose(0, 2, 1))
    fused_z = np.einsum("eab,eb->ea", fused_p, weighted)
    fused_e = np.stack([keys // n, keys % n], axis=1)
    return fused_e, fused_z, fused_p


def _adjacency(n: int, e: IntArray) -> csr_array:
    ones = np.ones(e.shape[0], dtype=np.int8)
    return csr_array(coo_array((ones, (e[:, 0], e[:, 1])), shape=(n, n)))


def _tree_solve(
    graph: csr_array,
    e: IntArray,
    z: FloatArray,
    p: FloatArray,
    r: int,
    x_r: FloatArray,
    positions: FloatArray,
    blocks: FloatArray | None,
) -> None:
    """Path sums from the reference over the tree ``e`` (0-based), written into the outputs."""
    n = graph.shape[0]
    order, pred = breadth_first_order(graph, r, directed=False, return_predecessors=True)
    nodes: IntArray = order[1:].astype(np.int64)
    parents: IntArray = pred[nodes].astype(np.int64)
    # the tree edge joining each node to its parent, by key lo·n + hi
    lo, hi = np.minimum(e[:, 0], e[:, 1]), np.maximum(e[:, 0], e[:, 1])
    keys = lo * n + hi
    sort = np.argsort(keys)
    want = np.minimum(nodes, parents) * n + np.maximum(nodes, parents)
    edge = sort[np.searchsorted(keys, want, sorter=sort)]
    # z_e = x_i − x_j, so x_node − x_parent = +z_e when the node is i, −z_e when it is j
    sign = np.where(e[edge, 0] == nodes, 1.0, -1.0)
    anc = np.arange(n)
    anc[nodes] = parents
    rel = np.zeros((n, z.shape[1]))
    rel[nodes] = sign[:, None] * z[edge]
    acc = None
    if blocks is not None:
        acc = np.zeros((n, *p.shape[1:]))
        acc[nodes] = p[edge]
    # pointer jumping: rel[v] = x_v − x_anc[v]; doubling the jump each round
    while True:
        up = anc[anc]
        if np.array_equal(up, anc):
            break
        rel = rel + rel[anc]
        if acc is not None:
            acc = acc + acc[anc]
        anc = up
    positions[nodes] = x_r + rel[nodes]
    if blocks is not None and acc is not None:
        blocks[nodes] = acc[nodes]
