"""Random problems of the leader's tests: graphs, SPD edge covariances, block systems.

Shared by tests/unit/leader (the BLUE, its covariances and their symbolic analysis) with
the dense oracle (:mod:`testkit.dense_oracle`) they are checked against.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from scipy.sparse import coo_array, csc_array

Kind = Literal["diagonal", "full", "scaled"]
TOL = 1e-9  # [m²] every block entry against the dense inverse


def random_graph(rng: np.random.Generator, n: int, extra: int, tree: bool) -> np.ndarray:
    """A random spanning tree of agents 1..n (plus ``extra`` random edges unless ``tree``)."""
    edges = [(k, int(rng.integers(1, k))) for k in range(2, n + 1)]
    while not tree and len(edges) < n - 1 + extra:
        a, b = (int(v) for v in rng.integers(1, n + 1, 2))
        if a != b:
            edges.append((a, b))
    out = np.array(edges, dtype=np.int64).reshape(-1, 2)
    flip = rng.random(len(out)) < 0.5
    return np.where(flip[:, None], out[:, ::-1], out)


def noise(rng: np.random.Generator, m: int, d: int, kind: Kind) -> np.ndarray:
    """(m, d, d) SPD covariances [m²]: diagonal, full with random correlations, or ``scaled``:
    one full matrix times a random scale per edge (the Kronecker structure)."""
    if kind == "diagonal":
        return rng.uniform(1e-4, 1.0, (m, d))[:, :, None] * np.eye(d)
    if kind == "scaled":
        a = rng.standard_normal((d, d))
        return rng.uniform(0.01, 1.0, (m, 1, 1)) * (a @ a.T + 1e-2 * np.eye(d))
    a = rng.standard_normal((m, d, d)) * rng.uniform(0.01, 1.0, (m, 1, 1))
    return a @ a.transpose(0, 2, 1) + 1e-3 * np.eye(d)


def block_system(rng: np.random.Generator, nodes: int, block: int, extra: int) -> csc_array:
    """A sparse SPD matrix of ``nodes`` × ``block`` unknowns coupled like a grounded Laplacian."""
    edges = random_graph(rng, nodes + 1, extra, False) - 1  # node 0 is grounded away
    w = noise(rng, len(edges), block, "full")
    inv_w = np.linalg.inv(w)
    rows, cols, vals = [], [], []
    a = np.arange(block)
    for (i, j), m in zip(edges.tolist(), inv_w, strict=True):
        for p, q, s in ((i, i, 1.0), (j, j, 1.0), (i, j, -1.0), (j, i, -1.0)):
            if p and q:
                rows.append(np.repeat((p - 1) * block + a, block))
                cols.append(np.tile((q - 1) * block + a, block))
                vals.append(s * m.ravel())
    size = nodes * block
    coo = coo_array(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), (size, size)
    )
    return csc_array(coo)
