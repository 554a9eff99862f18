"""Best linear unbiased estimate of every agent's position from relative measurements (MODEL.md §5).

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

A cyclic system is solved by sparse LU (SuperLU, minimum-degree ordering; the
matrix is SPD so no pivoting is needed) when the structure promises little
fill, else by conjugate gradients with a (block-)Jacobi preconditioner to a
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
from typing import Literal, Protocol

import numpy as np
import numpy.typing as npt
from scipy.sparse import coo_array, csr_array
from scipy.sparse.csgraph import (
    breadth_first_order,
    connected_components,
    dijkstra,
    reverse_cuthill_mckee,
)
from scipy.sparse.linalg import splu

from formation.graph import (
    AgentIdError,
    GraphInputError,
    ShapeError,
    as_edge_array,
    as_edge_mask,
    check_agent_count,
)

__all__ = ["BlueResult", "CovarianceError", "Solver", "blue", "nees"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]
Solver = Literal["auto", "tree", "direct", "cg"]

CG_RTOL = 1e-12
"""Relative residual ``‖b − A x‖ / ‖b‖`` at which conjugate gradients stop, per right-hand side."""
DIRECT_MAX_UNKNOWNS = 2048
"""Systems up to this many unknowns are always factorised (cheap, and exact covariances need it)."""
DIRECT_WORK_RATIO = 10.0
"""Factorise when the envelope bound on direct work is at most this times the CG work estimate."""
CG_ITERATIONS_PER_LEVEL = 8
"""CG iterations per BFS level from the reference, measured (Jacobi-PCG to 1e-12)."""
INVERSE_CHUNK_COLUMNS = 256
"""Identity columns solved at once when extracting covariance blocks from the factorisation."""
SYMMETRY_RTOL = 1e-10
"""A covariance counts as symmetric when ``|P − Pᵀ| ≤ 1e-10 · max|P|``."""


class _Factor(Protocol):
    """What the code needs of a sparse factorisation (``scipy.sparse.linalg.SuperLU``)."""

    shape: tuple[int, int]

    def solve(self, rhs: FloatArray) -> FloatArray: ...


class CovarianceError(GraphInputError):
    """A measurement covariance that is not symmetric positive definite."""


@dataclass(frozen=True, eq=False)
class BlueResult:
    """The BLUE of one epoch (MODEL.md §5).

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
    """BLUE of all agents' positions relative to the reference (MODEL.md §5).

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
    """Normalised estimation error squared per agent (MODEL.md §5, "Consistency").

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


# --------------------------------------------------------------------------- cyclic graphs


class _System:
    """The grounded weighted Laplacian system of the reference's component (module docstring)."""

    def __init__(
        self,
        n: int,
        r: int,
        observable: BoolArray,
        e: IntArray,
        z: FloatArray,
        p: FloatArray,
        x_r: FloatArray,
        diagonal: bool,
    ) -> None:
        self.d = z.shape[1]
        self.nodes: IntArray = np.flatnonzero(observable & (np.arange(n) != r))
        self.size = self.nodes.size
        local = np.full(n, self.size, dtype=np.int64)  # the reference maps to a dropped slot
        local[self.nodes] = np.arange(self.size)
        self.i, self.j = local[e[:, 0]], local[e[:, 1]]
        # y_e = z_e − (H_r x_r)_e: +x_r enters z_e when r is i, −x_r when r is j
        y = z.copy()
        y[e[:, 0] == r] -= x_r
        y[e[:, 1] == r] += x_r
        self.y = y
        self.p = p
        self.diagonal = diagonal
        self.method = ""
        self._first: csr_array | None = None

    # -- structure

    def pattern(self) -> csr_array:
        """Node-level sparsity of the grounded Laplacian, with its diagonal.

        In the diagonal case this is the first coordinate's Laplacian itself,
        kept so that ``solve`` does not assemble it twice.
        """
        if self.diagonal:
            if self._first is None:
                self._first = self._laplacian(self._weights()[:, 0])
            return self._first
        return self._laplacian(np.ones(self.i.size))

    def _weights(self) -> FloatArray:
        """Edge weights ``1 / P_e[k, k]`` per coordinate (diagonal case): (m, d)."""
        d = self.d
        w: FloatArray = 1.0 / self.p[:, np.arange(d), np.arange(d)]
        return w

    def _laplacian(self, w: FloatArray) -> csr_array:
        i, j, s = self.i, self.j, self.size
        rows = np.concatenate([i, j, i, j])
        cols = np.concatenate([i, j, j, i])
        vals = np.concatenate([w, w, -w, -w])
        keep = (rows < s) & (cols < s)
        return csr_array(coo_array((vals[keep], (rows[keep], cols[keep])), shape=(s, s)))

    def _block_laplacian(self) -> tuple[csr_array, FloatArray]:
        """``A = H_bᵀ P⁻¹ H_b`` in node-major order (unknown ``t·d + a``) and ``H_bᵀ P⁻¹ y``."""
        d, s = self.d, self.size
        w = np.linalg.inv(self.p)  # (m, d, d), symmetric
        a = np.arange(d)
        blocks = [
            (self.i, self.i, w),
            (self.j, self.j, w),
            (self.i, self.j, -w),
            (self.j, self.i, -w),
        ]
        rows, cols, vals = [], [], []
        for bi, bj, bw in blocks:
            keep = (bi < s) & (bj < s)
            rr = bi[keep, None, None] * d + a[None, :, None]
            cc = bj[keep, None, None] * d + a[None, None, :]
            rows.append(np.broadcast_to(rr, bw[keep].shape).ravel())
            cols.append(np.broadcast_to(cc, bw[keep].shape).ravel())
            vals.append(bw[keep].ravel())
        n_unk = s * d
        mat = csr_array(
            coo_array(
                (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                shape=(n_unk, n_unk),
            )
        )
        wy = np.einsum("eab,eb->ea", w, self.y)
        rhs = np.zeros((s + 1, d))
        np.add.at(rhs, self.i, wy)
        np.add.at(rhs, self.j, -wy)
        return mat, rhs[:s].reshape(n_unk, 1)

    def _rhs(self, w: FloatArray, cols: list[int]) -> FloatArray:
        """``H_bᵀ W y`` for coordinates ``cols`` with edge weights ``w``: (size, len(cols))."""
        s = self.size
        wy = w[:, None] * self.y[:, cols]
        out = np.zeros((s + 1, len(cols)))
        for c in range(len(cols)):
            out[:, c] = np.bincount(self.i, wy[:, c], minlength=s + 1) - np.bincount(
                self.j, wy[:, c], minlength=s + 1
            )
        return out[:s]

    # -- solve

    def solve(self, method: str, positions: FloatArray, blocks: FloatArray | None) -> None:
        """Solve for the estimates (and covariance blocks) and write them into the outputs."""
        d, s = self.d, self.size
        est = np.empty((s, d))
        cov = np.zeros((s, d, d)) if blocks is not None else None
        used: set[str] = set()
        if self.diagonal:
            weights = self._weights()
            for cols in _equal_columns(weights):
                if cols[0] == 0 and self._first is not None:
                    mat = self._first
                else:
                    mat = self._laplacian(weights[:, cols[0]])
                rhs = self._rhs(weights[:, cols[0]], cols)
                sol, how, lu = _solve(mat, rhs, method, None)
                used.add(how)
                est[:, cols] = sol
                if cov is not None:
                    var = _diagonal_blocks_of_inverse(lu if lu is not None else _factor(mat), 1)
                    for c in cols:
                        cov[:, c, c] = var[:, 0, 0]
        else:
            mat, rhs = self._block_laplacian()
            sol, how, lu = _solve(mat, rhs, method, d)
            used.add(how)
            est[:] = sol.reshape(s, d)
            if cov is not None:
                cov[:] = _diagonal_blocks_of_inverse(lu if lu is not None else _factor(mat), d)
        self.method = "cg" if "cg" in used else "direct"
        positions[self.nodes] = est
        if blocks is not None and cov is not None:
            blocks[self.nodes] = cov


def _equal_columns(weights: FloatArray) -> list[list[int]]:
    """Group coordinates whose edge weights are identical (they share one Laplacian)."""
    groups: list[list[int]] = []
    for c in range(weights.shape[1]):
        for g in groups:
            if np.array_equal(weights[:, g[0]], weights[:, c]):
                g.append(c)
                break
        else:
            groups.append([c])
    return groups


def _choose_method(system: _System, graph: csr_array, r: int) -> str:
    """``"direct"`` when the structure promises little fill, else ``"cg"`` (module docstring)."""
    unknowns = system.size * (1 if system.diagonal else system.d)
    if unknowns <= DIRECT_MAX_UNKNOWNS:
        return "direct"
    pat = system.pattern()
    perm = reverse_cuthill_mckee(pat, symmetric_mode=True)
    permuted = csr_array(pat[perm][:, perm])
    first = np.minimum.reduceat(permuted.indices, permuted.indptr[:-1])
    width = np.maximum(np.arange(system.size) - first, 0).astype(np.float64)
    dist = dijkstra(graph, directed=False, indices=r, unweighted=True)
    depth = float(dist[np.isfinite(dist)].max())
    block = 1 if system.diagonal else system.d
    direct_work = float(width @ width) * block  # blocks: d³ flops per entry vs d² for CG
    cg_work = CG_ITERATIONS_PER_LEVEL * depth * (2 * pat.nnz + 12 * system.size)
    return "direct" if direct_work <= DIRECT_WORK_RATIO * cg_work else "cg"


def _factor(mat: csr_array) -> _Factor:
    # SPD: symmetric ordering and no pivoting are safe and keep the factor small
    lu: _Factor = splu(
        mat.tocsc(),
        permc_spec="MMD_AT_PLUS_A",
        diag_pivot_thresh=0.0,
        options={"SymmetricMode": True},
    )
    return lu


def _solve(
    mat: csr_array, rhs: FloatArray, method: str, block: int | None
) -> tuple[FloatArray, str, _Factor | None]:
    """Solve ``mat @ x = rhs``; returns the solution, the method used and the factor if any."""
    if method == "cg":
        sol = _pcg(mat, rhs, block)
        if sol is not None:
            return sol, "cg", None
    lu = _factor(mat)
    out = np.asarray(lu.solve(np.asfortranarray(rhs)))
    return out.reshape(rhs.shape), "direct", lu


def _pcg(mat: csr_array, rhs: FloatArray, block: int | None) -> FloatArray | None:
    """Preconditioned conjugate gradients for every column of ``rhs`` at once.

    Jacobi preconditioner (``block=None``) or block-Jacobi with ``block × block``
    diagonal blocks. Stops when every column's residual is below ``CG_RTOL`` of
    its right-hand side; returns ``None`` if that takes more than ``10 n + 100``
    iterations (the caller then factorises). Works on the transposed layout
    (one contiguous row per right-hand side) so the inner products are fast.
    """
    size = rhs.shape[0]
    if block is None:
        inv_diag = 1.0 / mat.diagonal()

        def precond(v: FloatArray) -> FloatArray:
            out: FloatArray = v * inv_diag
            return out
    else:
        nodes = size // block
        inv_blocks = np.linalg.inv(_diag_blocks(mat, block))

        def precond(v: FloatArray) -> FloatArray:
            out: FloatArray = np.einsum(
                "tab,ktb->kta", inv_blocks, v.reshape(-1, nodes, block)
            ).reshape(v.shape)
            return out

    def apply(v: FloatArray) -> FloatArray:
        out = np.empty_like(v)
        for k in range(v.shape[0]):
            out[k] = mat @ v[k]
        return out

    b = np.ascontiguousarray(rhs.T)
    x = np.zeros_like(b)
    res = b.copy()
    target = CG_RTOL**2 * np.einsum("ij,ij->i", b, b)
    if not np.any(target > 0):
        return x.T.copy()
    zv = precond(res)
    direction = zv.copy()
    rz = np.einsum("ij,ij->i", res, zv)
    for _ in range(10 * size + 100):
        ad = apply(direction)
        curv = np.einsum("ij,ij->i", direction, ad)
        alpha = np.divide(rz, curv, out=np.zeros_like(rz), where=curv > 0)[:, None]
        x += alpha * direction
        res -= alpha * ad
        if np.all(np.einsum("ij,ij->i", res, res) <= target):
            return x.T.copy()
        zv = precond(res)
        rz_new = np.einsum("ij,ij->i", res, zv)
        beta = np.divide(rz_new, rz, out=np.zeros_like(rz), where=rz > 0)[:, None]
        direction = zv + beta * direction
        rz = rz_new
    return None


def _diag_blocks(mat: csr_array, block: int) -> FloatArray:
    """The ``block × block`` diagonal blocks of a sparse matrix: (size / block, block, block)."""
    coo = mat.tocoo()
    same = coo.row // block == coo.col // block
    out = np.zeros((mat.shape[0] // block, block, block))
    np.add.at(
        out, (coo.row[same] // block, coo.row[same] % block, coo.col[same] % block), coo.data[same]
    )
    return out


def _diagonal_blocks_of_inverse(lu: _Factor, block: int) -> FloatArray:
    """Diagonal ``block × block`` blocks of ``A⁻¹`` from a factorisation of ``A``.

    Solves against ``INVERSE_CHUNK_COLUMNS`` identity columns at a time and keeps
    the diagonal blocks: exact, ``O(size · nnz(LU))`` work, never the dense inverse.
    """
    size = lu.shape[0]
    nodes = size // block
    per = max(1, INVERSE_CHUNK_COLUMNS // block) if size > DIRECT_MAX_UNKNOWNS else nodes
    out = np.empty((nodes, block, block))
    for start in range(0, nodes, per):
        k = min(per, nodes - start)
        eye = np.zeros((size, k * block), order="F")
        eye[start * block + np.arange(k * block), np.arange(k * block)] = 1.0
        sol = lu.solve(eye).reshape(nodes, block, k, block)
        got = sol[start + np.arange(k), :, np.arange(k), :]
        out[start : start + k] = 0.5 * (got + got.transpose(0, 2, 1))
    return out
