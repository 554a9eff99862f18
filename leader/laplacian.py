"""The grounded weighted Laplacian of the BLUE on a cyclic graph: assembly and solves (docs/model.md §5).

``A = H_bᵀ P⁻¹ H_b`` on the reference's component, assembled sparse (one
Laplacian per coordinate when every ``P_e`` is diagonal, ``d × d`` blocks
otherwise), solved by sparse LU (in the fill-reducing order of its pattern, analysed once per
pattern: ``leader.symbolic``) or preconditioned conjugate gradients, with the
diagonal blocks of ``A⁻¹`` as covariances (selected inversion over the LU
factor, ``leader.covariance``). ``leader.estimation``'s docstring explains how the
solver is chosen.

**Kronecker structure.** When every ``P_e = c_e R`` for one full ``d × d`` ``R``
(one sensor's noise, scaled per edge), ``A = L_w ⊗ R⁻¹`` with ``L_w`` the scalar
grounded Laplacian weighted by ``w_e = 1 / c_e``, so ``A⁻¹ = L_w⁻¹ ⊗ R``: agent
``t``'s block is ``(L_w⁻¹)_tt R``, and ``L_w X = H_bᵀ W Y`` gives the estimates
(``R`` cancels). One ``n_b × n_b`` factorisation and selected inversion instead
of the ``n_b d × n_b d`` block one: ``d³`` fewer flops in the dense core, ``d²``
fewer gathers. :func:`common_shape` detects it (``P_e`` equal to ``c_e R`` to
``SHAPE_RTOL``, rounding); otherwise the block system is solved.
"""

from __future__ import annotations

import logging

import numpy as np
import numpy.typing as npt
from scipy.sparse import coo_array, csr_array
from scipy.sparse.csgraph import dijkstra, reverse_cuthill_mckee

from leader.covariance import PatternError, inverse_diagonal_blocks
from leader.symbolic import PermutedFactor, factorise
from leader.tree import adjacency

__all__ = ["CG_RTOL", "DIRECT_MAX_UNKNOWNS", "GroundedSystem", "choose_method", "common_shape"]

log = logging.getLogger("leader")

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

CG_RTOL = 1e-12
"""Relative residual ``‖b − A x‖ / ‖b‖`` at which conjugate gradients stop, per right-hand side."""
DIRECT_MAX_UNKNOWNS = 2048
"""Systems up to this many unknowns are always factorised (cheap, and exact covariances need it)."""
DIRECT_WORK_RATIO = 10.0
"""Factorise when the envelope bound on direct work is at most this times the CG work estimate."""
CG_ITERATIONS_PER_LEVEL = 8
"""CG iterations per BFS level from the reference, measured (Jacobi-PCG to 1e-12)."""
INVERSE_CHUNK_COLUMNS = 256
"""Identity columns solved at once when the selected inversion cannot read the factor."""
SHAPE_RTOL = 1e-12
"""``P_e`` counts as ``c_e R`` when no entry is off by more than this times ``max |P_e|``."""


class GroundedSystem:
    """The grounded weighted Laplacian system of the reference's component (``leader.estimation``).

    Parameters
    ----------
    n : agents; r : the reference (0-based); observable : (n,) the reference's component
    e : (k, 2) used links inside the component, 0-based; z : (k, d) ``x_i − x_j`` measured [m]
    p : (k, d, d) their noise covariances [m²]; x_r : (d,) the reference's position [m]
    diagonal : every ``p[e]`` is diagonal (the ``d`` coordinates decouple)

    ``shape`` is ``R`` when the full ``p`` have the Kronecker structure (:func:`common_shape`),
    else ``None``; then, as in the diagonal case, the systems are scalar (``block == 1``).
    """

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
        self.scale: FloatArray | None = None
        self.shape: FloatArray | None = None
        if not diagonal:
            found = common_shape(p)
            if found is not None:
                self.scale, self.shape = found
        self.block = 1 if diagonal or self.shape is not None else self.d
        self.method = ""
        self._first: csr_array | None = None

    # -- structure

    def pattern(self) -> csr_array:
        """Node-level sparsity of the grounded Laplacian, with its diagonal.

        For scalar systems this is the first coordinate's Laplacian itself,
        kept so that ``solve`` does not assemble it twice.
        """
        if self.block == 1:
            if self._first is None:
                self._first = self._laplacian(self._weights()[:, 0])
            return self._first
        return self._laplacian(np.ones(self.i.size))

    def _weights(self) -> FloatArray:
        """Edge weights per coordinate of the scalar systems: ``1 / P_e[k, k]``, or ``1 / c_e``
        for all ``k`` with the Kronecker structure: (m, d)."""
        d = self.d
        if self.scale is not None:
            return np.repeat(1.0 / self.scale[:, None], d, axis=1)
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
        if self.block == 1:
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
                    var = _covariance_blocks(lu if lu is not None else factorise(mat), 1)
                    if self.shape is not None:  # one group of all d: A⁻¹ = L_w⁻¹ ⊗ R
                        cov[:] = var[:, 0, 0, None, None] * self.shape
                    else:
                        cov[:, cols, cols] = var[:, :1, 0]
        else:
            mat, rhs = self._block_laplacian()
            sol, how, lu = _solve(mat, rhs, method, d)
            used.add(how)
            est[:] = sol.reshape(s, d)
            if cov is not None:
                cov[:] = _covariance_blocks(lu if lu is not None else factorise(mat), d)
        self.method = "cg" if "cg" in used else "direct"
        positions[self.nodes] = est
        if blocks is not None and cov is not None:
            blocks[self.nodes] = cov


def common_shape(p: FloatArray) -> tuple[FloatArray, FloatArray] | None:
    """``(c, R)`` with ``p[e] = c[e] R`` for every edge (to ``SHAPE_RTOL``), or ``None``.

    Parameters
    ----------
    p : (m, d, d) SPD covariances [m²]

    Returns
    -------
    c : (m,) positive scales; R : (d, d) ``p[0]`` (so ``c[0] = 1``)
    """
    if p.shape[0] == 0:
        return None
    shape = p[0]
    # least-squares scale per edge; positive since both are SPD (Frobenius product)
    scale = np.einsum("eab,ab->e", p, shape) / float(np.einsum("ab,ab->", shape, shape))
    off = np.abs(p - scale[:, None, None] * shape).max(axis=(1, 2))
    if (off > SHAPE_RTOL * np.abs(p).max(axis=(1, 2))).any():
        return None
    return scale, shape


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


def choose_method(system: GroundedSystem, links: IntArray, r: int) -> str:
    """``"direct"`` when the structure promises little fill, else ``"cg"`` (``leader.estimation``).

    ``links`` (k, 2): the used links, 0-based, for the BFS depth from ``r``; read only for a
    system too large to factorise unasked.
    """
    unknowns = system.size * system.block
    if unknowns <= DIRECT_MAX_UNKNOWNS:
        return "direct"
    graph = adjacency(max(r, int(links.max(initial=0))) + 1, links)
    pat = system.pattern()
    perm = reverse_cuthill_mckee(pat, symmetric_mode=True)
    permuted = csr_array(pat[perm][:, perm])
    first = np.minimum.reduceat(permuted.indices, permuted.indptr[:-1])
    width = np.maximum(np.arange(system.size) - first, 0).astype(np.float64)
    dist = dijkstra(graph, directed=False, indices=r, unweighted=True)
    depth = float(dist[np.isfinite(dist)].max())
    block = system.block
    direct_work = float(width @ width) * block  # blocks: d³ flops per entry vs d² for CG
    cg_work = CG_ITERATIONS_PER_LEVEL * depth * (2 * pat.nnz + 12 * system.size)
    return "direct" if direct_work <= DIRECT_WORK_RATIO * cg_work else "cg"


def _solve(
    mat: csr_array, rhs: FloatArray, method: str, block: int | None
) -> tuple[FloatArray, str, PermutedFactor | None]:
    """Solve ``mat @ x = rhs``; returns the solution, the method used and the factor if any."""
    if method == "cg":
        sol = _pcg(mat, rhs, block)
        if sol is not None:
            return sol, "cg", None
    lu = factorise(mat)
    return lu.solve(rhs), "direct", lu


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


def _covariance_blocks(lu: PermutedFactor, block: int) -> FloatArray:
    """Diagonal ``block × block`` blocks of ``A⁻¹``: selected inversion of the factor."""
    try:
        return inverse_diagonal_blocks(lu, block, plans=lu.plans)
    except PatternError as err:  # not seen with SuperLU's symmetric mode; exact either way
        log.warning("covariances by identity-column solves: %s", err)
        return _diagonal_blocks_by_solves(lu, block)


def _diagonal_blocks_by_solves(lu: PermutedFactor, block: int) -> FloatArray:
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
