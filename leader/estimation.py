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
  (independent noises add). Both by pointer jumping over the BFS tree,
  ``O(n log depth)`` (``leader.tree``).
* **diagonal** ``P_e`` (scalar-times-identity or any diagonal): the ``d``
  coordinates decouple, ``A = ⊕_k L_k`` with ``L_k`` the ``n_b × n_b`` grounded
  Laplacian weighted by ``1 / P_e[k, k]``; coordinates with equal weights share
  one matrix (one factorisation for all ``d`` when ``P_e = σ_e² I``).
* **full** ``P_e``: the block system, blocks ``±P_e⁻¹``; if all ``P_e = c_e R``, ``L_w ⊗ R⁻¹``.

A cyclic system (``leader.laplacian``) is solved by sparse LU (SuperLU,
minimum-degree ordering; the matrix is SPD so no pivoting is needed) when the
structure promises little fill, else by conjugate gradients with a (block-)Jacobi preconditioner to a
relative residual of 1e-12. The promise is judged from the graph: the squared
envelope of a reverse Cuthill–McKee ordering (an upper bound on a direct
factorisation's work) against ``8 × BFS depth`` CG iterations (measured on
formation-like and expander graphs, bench/bench_leader.py). Planar formation
graphs factor cheaply; expanders fill in badly but are well conditioned.

Covariance blocks on a cyclic graph are the ``d × d`` diagonal blocks of
``A⁻¹``, by selected inversion of the LU factorisation (Takahashi's recurrences
on the factor's pattern, its dense trailing fronts by LAPACK; ``leader.covariance``):
exact, never the dense inverse, tens of milliseconds at 10,000 agents of a
formation-like graph and about a second on an expander (bench/bench_leader.py).
Pass ``covariances=False`` to skip it.

:func:`blue` is one epoch of one run; :meth:`MeasurementGraph.estimate` is one
epoch of ``B`` independent runs of one graph (a batch of seeds), and :func:`blue`
is its batch of one. The batch is one graph of ``B·n`` agents (member ``b``'s agent ``i`` is
``b·n + i``): components and fusion are found for all members at once, every
member whose used graph is a tree is solved in one pass of path sums, and a
member with cycles gets its own grounded system. Each member gets the floats it
would get alone, so a run of a batch equals the run of the leader process.
"""

from __future__ import annotations

import operator
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt
from scipy.sparse.csgraph import connected_components

from formation import check_dimension
from formation.errors import AgentIdError, CovarianceError, GraphInputError, ShapeError
from formation.graph import as_edge_array, as_edge_mask, check_agent_count
from leader.dense import dense_blue
from leader.laplacian import GroundedSystem, choose_method
from leader.tree import adjacency, fuse_parallel, tree_solve

__all__ = [
    "BlueBatch",
    "BlueResult",
    "MeasurementGraph",
    "Solver",
    "blue",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]
Solver = Literal["auto", "tree", "direct", "cg", "dense"]

SYMMETRY_RTOL = 1e-10
"""A covariance counts as symmetric when ``|P − Pᵀ| ≤ 1e-10 · max|P|``."""


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


@dataclass(frozen=True, eq=False)
class BlueBatch:
    """The BLUE of ``B`` independent members of one graph at one epoch (docs/model.md §5).

    Attributes
    ----------
    positions : (B, n, d) float64 array [m]
        Member ``b``'s :attr:`BlueResult.positions` in row ``b``.
    covariances : (B, n, d, d) float64 array [m²] or None
        Likewise the covariance blocks; ``None`` when not requested.
    observable : (B, n) bool array
        Agents joined to the reference by the member's used edges.
    solvers : tuple of str, one per member
        As :attr:`BlueResult.solver`.
    """

    positions: FloatArray
    covariances: FloatArray | None
    observable: BoolArray
    solvers: tuple[str, ...]

    def member(self, b: int) -> BlueResult:
        """Member ``b`` as the one-run result."""
        cov = None if self.covariances is None else self.covariances[b]
        return BlueResult(self.positions[b], cov, self.observable[b], self.solvers[b])


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
        cyclic solvers (``"cg"`` still factorises for covariance blocks);
        ``"dense"`` (``leader.dense``, small teams) needs one covariance for every edge.

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
    m = as_edge_array(check_agent_count(n), edges).shape[0]
    if np.ndim(cov) == 2:  # one covariance for all is MeasurementGraph's, not blue's
        raise ShapeError("cov", np.shape(cov), f"({m}, {d}, {d})")
    graph = MeasurementGraph.of(n, d, edges, cov, ref)
    zz = _as_finite(z, "z", (m, graph.d), "measurements")
    used = as_edge_mask(use, m, "use")
    batch = graph.estimate(zz[None], x_ref, used[None], covariances=covariances, solver=solver)
    return batch.member(0)


@dataclass(frozen=True, eq=False)
class MeasurementGraph:
    """Oriented measurement edges, their noise and the reference, checked once for many epochs.

    :meth:`estimate` is the BLUE of a batch of members over this graph; :func:`blue` is its
    batch of one.

    n, d : agents and dimension; edges : (m, 2) 0-based ``(i, j)``; cov : (m, d, d) [m²];
    ref : the reference, 0-based; diagonal : every ``cov[e]`` is diagonal
    """

    n: int
    d: int
    edges: IntArray
    cov: FloatArray
    ref: int
    diagonal: bool

    @classmethod
    def of(
        cls, n: int, d: int, edges: npt.ArrayLike, cov: npt.ArrayLike, ref: int
    ) -> MeasurementGraph:
        """Check the graph as :func:`blue` does; ``cov`` is (m, d, d), or (d, d) for every edge."""
        count = check_agent_count(n)
        dim = check_dimension(d)
        e = as_edge_array(count, edges)
        m = e.shape[0]
        shared = np.ndim(cov) == 2
        pp = _as_finite(cov, "cov", (dim, dim) if shared else (m, dim, dim), "covariances")
        pp = pp[None] if shared else pp
        diagonal = _check_covariances(pp)
        pp = np.broadcast_to(pp, (m, dim, dim)) if shared else pp
        return cls(count, dim, e - 1, pp, _check_ref(ref, count), diagonal)

    def estimate(
        self,
        z: npt.ArrayLike,
        x_ref: npt.ArrayLike,
        use: BoolArray,
        *,
        covariances: bool = True,
        solver: Solver = "auto",
        labels: IntArray | None = None,
    ) -> BlueBatch:
        """The BLUE of ``B`` members of this graph at once; member ``b`` as :func:`blue` alone.

        Parameters
        ----------
        z : (B, m, d) array_like [m]
            Member ``b``'s measurements in row ``b``. Not checked for finiteness: a
            member whose used measurements are not finite (a diverged run) gets
            non-finite estimates, and the other members are not affected.
        x_ref : (d,) array_like [m]
            The reference's known position, the same in every member.
        use : (B, m) bool array
            The measurements each member uses.
        covariances, solver
            As in :func:`blue`.
        labels : (B, n) int array, optional
            Component labels of each member's used graph, when the caller has them
            (the leader's Kruskal forest spans it); not checked.

        Returns
        -------
        BlueBatch
            Member ``b`` equal, bit for bit, to :func:`blue` on member ``b`` alone.
        """
        m, dim = self.edges.shape[0], self.d
        zz = np.asarray(z, dtype=np.float64)
        if zz.ndim != 3 or zz.shape[1:] != (m, dim) or zz.shape[0] < 1:
            raise ShapeError("z", zz.shape, f"(B, {m}, {dim}) with B ≥ 1")
        if use.shape != zz.shape[:2] or use.dtype != np.bool_:
            raise ShapeError("use", use.shape, f"{zz.shape[:2]} bool")
        xr = _as_finite(x_ref, "x_ref", (dim,), "coordinates")
        _check_solver(solver)
        return _estimate(
            self.n,
            self.edges,
            zz,
            self.cov,
            self.ref,
            xr,
            use,
            self.diagonal,
            covariances,
            solver,
            labels,
        )


def _estimate(
    n: int,
    e: IntArray,
    z: FloatArray,
    p: FloatArray,
    r: int,
    x_r: FloatArray,
    used: BoolArray,
    diagonal: bool,
    covariances: bool,
    solver: Solver,
    labels: IntArray | None = None,
) -> BlueBatch:
    """The BLUE of every member: ``e`` (m, 2) 0-based, ``z`` (B, m, d), ``used`` (B, m), ``r`` 0-based.

    ``labels`` (B, n): the components of the used graphs, if known.
    """
    size, m, dim = z.shape
    flat = np.flatnonzero(used)  # member-major, each member's edges in their order
    member, edge = np.divmod(flat, m)
    zq = z.reshape(-1, dim)[flat]
    if solver == "dense":
        if p.shape[0] and not (p == p[0]).all():
            raise GraphInputError(
                "solver = 'dense' with different covariances", "one covariance for every edge"
            )
        shared = p[0] if p.shape[0] else np.eye(dim)
        reach = None if labels is None else labels == labels[:, r : r + 1]
        pos, cov, obs = dense_blue(size, n, member, e[edge], zq, shared, r, x_r, covariances, reach)
        names = tuple("dense" if k > 1 else "none" for k in obs.sum(axis=1).tolist())
        return BlueBatch(pos, cov, obs, names)
    ue = e[edge] + (member * n)[:, None]  # agent i of member b is b·n + i
    graph = None
    if labels is None:
        graph = adjacency(size * n, ue)
        labels = connected_components(graph, directed=False)[1].reshape(size, n)
    observable: BoolArray = labels == labels[:, r : r + 1]
    inside = observable.reshape(-1)[ue[:, 0]]  # used edges within the reference's component
    fe, fz, fp = fuse_parallel(size * n, ue[inside], zq[inside], p[edge[inside]])
    owner = fe[:, 0] // n
    agents = observable.sum(axis=1)
    links = np.bincount(owner, minlength=size)
    is_tree = links == agents - 1

    positions = np.full((size, n, dim), np.nan)
    positions[:, r] = x_r
    blocks = np.full((size, n, dim, dim), np.nan) if covariances else None
    if blocks is not None:
        blocks[:, r] = 0.0
    solvers = ["none"] * size
    alone = agents > 1
    if solver == "tree" and (alone & ~is_tree).any():
        b = int(np.flatnonzero(alone & ~is_tree)[0])
        raise GraphInputError(
            f"solver = 'tree' but the reference's component has {agents[b]} agents and "
            f"{links[b]} distinct used links",
            f"{agents[b] - 1} (a tree)",
        )
    on_tree = alone & is_tree if solver in ("auto", "tree") else np.zeros(size, dtype=bool)
    if on_tree.any():
        mine = slice(None) if on_tree.all() else on_tree[owner]
        tree_solve(
            size * n,
            fe[mine],
            fz[mine],
            fp[mine],
            np.flatnonzero(on_tree) * n + r,
            x_r,
            positions.reshape(size * n, dim),
            None if blocks is None else blocks.reshape(size * n, dim, dim),
            graph,
        )
        for b in np.flatnonzero(on_tree).tolist():
            solvers[b] = "tree"
    for b in np.flatnonzero(alone & ~on_tree).tolist():
        mine = owner == b
        system = GroundedSystem(
            n, r, observable[b], fe[mine] - b * n, fz[mine], fp[mine], x_r, diagonal
        )
        method = choose_method(system, ue[member == b] - b * n, r) if solver == "auto" else solver
        system.solve(method, positions[b], None if blocks is None else blocks[b])
        solvers[b] = system.method
    return BlueBatch(positions, blocks, observable, tuple(solvers))


# --------------------------------------------------------------------------- input checks


def _check_solver(solver: str) -> None:
    if solver not in ("auto", "tree", "direct", "cg", "dense"):
        raise GraphInputError(f"solver = {solver!r}", "'auto', 'tree', 'direct', 'cg' or 'dense'")


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
