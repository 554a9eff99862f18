"""The dense BLUE oracle of the tests and benches: the normal equations, one dense solve.

An independent reference for ``leader.blue`` (docs/model.md §5), sharing none of its
code: every used measurement ``z_e = x_i − x_j + ε_e``, ``ε_e ~ N(0, P_e)``, adds
``H_eᵀ P_e⁻¹ H_e`` to the information matrix ``A`` and ``H_eᵀ P_e⁻¹ y_e`` to ``b``,
where ``y_e`` is ``z_e`` with the reference's known position moved across. The
unknowns are the agents of the reference's component but the reference; then
``x̂ = A⁻¹ b`` by ``np.linalg.solve`` and ``Cov(x̂_v) = (A⁻¹)_vv`` by ``np.linalg.inv``.
Used by tests/unit/leader and bench/bench_leader.py as ``dense_system(...).solve()``; the
bench times ``solve`` alone, the assembly being a Python loop.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class DenseSystem:
    """The normal equations ``A u = b`` of a BLUE over the unknown agents ``nodes``."""

    n: int
    ref: int  # 1-based
    x_ref: FloatArray  # (d,) [m]
    nodes: list[int]  # 0-based agents of the unknowns, in order
    a: FloatArray  # (k d, k d) [m⁻²]
    b: FloatArray  # (k d,) [m⁻¹]

    def solve(self) -> tuple[FloatArray, FloatArray]:
        """``(positions (n, d) [m], covariance blocks (n, d, d) [m²])``: the reference at
        ``x_ref`` with a zero block, NaN off the reference's component."""
        d = self.x_ref.shape[0]
        positions = np.full((self.n, d), np.nan)
        blocks = np.full((self.n, d, d), np.nan)
        positions[self.ref - 1], blocks[self.ref - 1] = self.x_ref, 0.0
        k = len(self.nodes)
        if k:
            positions[self.nodes] = np.linalg.solve(self.a, self.b).reshape(k, d)
            inv = np.linalg.inv(self.a).reshape(k, d, k, d)
            blocks[self.nodes] = inv[np.arange(k), :, np.arange(k), :]
        return positions, blocks


def dense_system(
    n: int,
    edges: npt.NDArray[np.int64],
    z: FloatArray,
    cov: FloatArray,
    ref: int = 1,
    x_ref: FloatArray | None = None,
    use: npt.NDArray[np.bool_] | None = None,
    observable: npt.NDArray[np.bool_] | None = None,
) -> DenseSystem:
    """The normal equations of the BLUE of agents ``1..n``.

    Parameters
    ----------
    n : int
        Agents ``1..n``.
    edges : (m, 2) int array
        Measured pairs ``(i, j)``, 1-based.
    z : (m, d) float array [m]
        ``z_e = x_i − x_j + ε_e``.
    cov : (m, d, d) float array [m²]
        ``P_e``, the covariance of ``ε_e``.
    ref : int
        The reference, 1-based, at ``x_ref`` (d,) [m] (default the origin).
    use : (m,) bool array, optional
        The measurements used (default all).
    observable : (n,) bool array, optional
        The reference's component (default: reached from ``ref`` by used measurements).
    """
    d = z.shape[1]
    x0 = np.zeros(d) if x_ref is None else np.asarray(x_ref, dtype=np.float64)
    used = np.flatnonzero(np.ones(len(edges), bool) if use is None else use)
    pairs = [(int(edges[e, 0]) - 1, int(edges[e, 1]) - 1) for e in used]
    if observable is None:
        observable = np.zeros(n, bool)
        observable[ref - 1] = True
        grown = True
        while grown:  # one hop a round
            grown = False
            for i, j in pairs:
                if observable[i] != observable[j]:
                    observable[i] = observable[j] = grown = True
    nodes = [a for a in range(n) if observable[a] and a != ref - 1]
    col = {a: k * d for k, a in enumerate(nodes)}
    a_mat = np.zeros((len(nodes) * d, len(nodes) * d))
    b_vec = np.zeros(len(nodes) * d)
    for e, (i, j) in zip(used, pairs, strict=True):
        w = np.linalg.inv(cov[e])
        y = z[e] - x0 * (i == ref - 1) + x0 * (j == ref - 1)
        for p, sp in ((i, 1.0), (j, -1.0)):
            if p not in col:
                continue
            b_vec[col[p] : col[p] + d] += sp * (w @ y)
            for q, sq in ((i, 1.0), (j, -1.0)):
                if q in col:
                    a_mat[col[p] : col[p] + d, col[q] : col[q] + d] += sp * sq * w
    return DenseSystem(n, ref, x0, nodes, a_mat, b_vec)
