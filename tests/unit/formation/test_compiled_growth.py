"""The compiled growth rounds against the numpy reference: the same round for every agent, the
same determinant bound bit for bit (docs/model.md §2)."""

from __future__ import annotations

import numpy as np
from hypothesis import example, given, settings
from hypothesis import strategies as st

from formation.compiled_growth import bound_passes, largest_determinant
from formation.rigidity_growth import (
    _largest_determinants,
    _surely_spanning,
    growth_rounds,
    half_edges,
    reference_growth_rounds,
)
from testbed.sim.team_generators import rigid_team


def framework(n: int, d: int, seed: int, tilt: float) -> tuple[np.ndarray, np.ndarray]:
    """Random agents, some on a line (a plane in 3-D) tilted off it by ``tilt``, joined by a
    random graph: candidates the bound passes and ones it leaves to the SVD."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, d))
    flat = rng.random(n) < (0.4 if d > 1 else 0.0)
    x[flat, -1] = tilt * rng.normal(size=int(flat.sum()))
    pairs = np.array([(i, j) for i in range(1, n + 1) for j in range(i + 1, n + 1)])
    edges = pairs[rng.random(len(pairs)) < rng.uniform(0.1, 0.6)]
    return x, edges


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(4, 60),
    d=st.sampled_from([1, 2, 3, 4]),
    seed=st.integers(0, 10_000),
    tilt=st.sampled_from([0.0, 1e-12, 1e-9, 1e-6, 1.0]),
    loss=st.sampled_from([0.0, 0.1, 0.4]),
    from_body=st.booleans(),
)
@example(n=30, d=3, seed=1, tilt=1e-9, loss=0.1, from_body=False)
def test_the_compiled_rounds_are_the_references(
    n: int, d: int, seed: int, tilt: float, loss: float, from_body: bool
) -> None:
    x, edges = framework(n, d, seed, tilt)
    if edges.shape[0] == 0:
        return
    rng = np.random.default_rng(seed + 1)
    whole = half_edges(x, edges - 1)
    mask = rng.random(len(edges)) >= loss
    kept = edges[mask]
    for start in range(min(3, kept.shape[0])):
        seed_edge = int(rng.integers(kept.shape[0]))
        body = None
        if from_body and start == 0:  # the first rounds grown on every edge
            order = reference_growth_rounds(x, edges, half=whole)
            body = (order >= 0) & (order <= 2)
        want = reference_growth_rounds(x, kept, seed_edge, body=body)
        np.testing.assert_array_equal(growth_rounds(x, kept, seed_edge, body=body), want)
        np.testing.assert_array_equal(
            growth_rounds(x, kept, seed_edge, whole.kept(mask), body=body), want
        )


def test_a_large_team_grows_in_the_same_rounds() -> None:
    for d, lost in ((2, 0.02), (3, 0.05)):
        s = rigid_team(1500, d, 0.1, seed=4)
        x, edges = s.offsets, s.edge_array
        mask = np.random.default_rng(d).random(len(edges)) >= lost
        want = reference_growth_rounds(x, edges[mask])
        assert want.max() > 20  # many rounds, past the simplex
        np.testing.assert_array_equal(growth_rounds(x, edges[mask]), want)


@settings(max_examples=30, deadline=None)
@given(
    d=st.sampled_from([2, 3]),
    seed=st.integers(0, 10_000),
    tilt=st.sampled_from([0.0, 1e-15, 1e-12, 1e-9, 1e-6, 1.0]),
)
def test_the_compiled_determinants_are_numpys_bit_for_bit(d: int, seed: int, tilt: float) -> None:
    # (B, d + 1, d) unit rows, near a line (plane) by `tilt`; some zero rows, some NaN
    rng = np.random.default_rng(seed)
    s = rng.normal(size=(200, d + 1, d))
    s[..., -1] *= np.where(rng.random((200, 1)) < 0.5, tilt, 1.0)
    s /= np.linalg.norm(s, axis=2, keepdims=True)
    s[rng.random((200, d + 1)) < 0.15] = 0.0
    s[rng.random((200, d + 1)) < 0.02] = np.nan
    want = _largest_determinants(s)
    got = np.array([largest_determinant(np.ascontiguousarray(rows)) for rows in s])
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    finite = ~np.isnan(want)
    np.testing.assert_array_equal(got[finite].view(np.int64), want[finite].view(np.int64))


@settings(max_examples=20, deadline=None)
@given(d=st.sampled_from([2, 3]), seed=st.integers(0, 10_000))
def test_the_compiled_bound_passes_the_candidates_numpys_passes(d: int, seed: int) -> None:
    # 300 candidates of 1..8 half-edges, a third of them to agents outside the cluster; the
    # directions tilted off a line (plane) by 1e-10.5..1e-7: |δ| about the bound's threshold
    rng = np.random.default_rng(seed)
    degree = rng.integers(1, 9, size=300)
    start = np.concatenate([[0], np.cumsum(degree)])
    inside = rng.random(start[-1]) < 0.67
    head = np.arange(start[-1])  # half-edge h points to agent h: inside[h]
    dirs = rng.normal(size=(start[-1] + 1, d))
    tilt = 10.0 ** rng.uniform(-10.5, -7.0, size=300)
    dirs[:-1, -1] *= np.repeat(tilt, degree)
    dirs[:-1] /= np.linalg.norm(dirs[:-1], axis=1, keepdims=True)
    dirs[-1] = 0.0
    into = np.flatnonzero(inside)
    count = np.add.reduceat(inside.astype(np.int64), start[:-1])
    want = _surely_spanning(dirs, np.append(into, -1), np.cumsum(count) - count, count)
    rows = np.zeros((d + 1, d))
    scale = d ** ((d - 1) / 2)
    got = [
        bound_passes(dirs, head, start, inside, a, int(count[a]), scale, rows) for a in range(300)
    ]
    np.testing.assert_array_equal(got, want)
    assert 0 < want.sum() < (count >= d).sum()  # both answers near the threshold
