"""Safety counts: minimum inter-agent distance, collisions per pair, time out of the box."""

from __future__ import annotations

import numpy as np

from analysis.metrics import collisions, min_distance, pair_distances, time_out_of_bounds


def test_pair_distances_and_minimum() -> None:
    x = np.array([[[0.0, 0.0], [3.0, 4.0], [0.0, 1.0]], [[0.0, 0.0], [0.0, 0.2], [5.0, 5.0]]])
    np.testing.assert_allclose(pair_distances(x[0]), [5.0, 1.0, np.hypot(3.0, 3.0)])
    np.testing.assert_allclose(min_distance(x), [1.0, 0.2])
    assert min_distance(np.zeros((4, 1, 2))).tolist() == [np.inf] * 4


def test_collisions_count_contacts_per_pair_once_per_contact() -> None:
    gap = np.array([1.0, 0.05, 0.05, 1.0, 0.08, 1.0])  # 1–2 touch twice (epochs 1–2 and 4)
    x = np.zeros((6, 3, 2))
    x[:, 1, 0] = gap
    x[:, 2, 0] = 10.0
    pairs, counts = collisions(x, body_diameter_m=0.1)
    assert pairs.tolist() == [[1, 2]]
    assert counts.tolist() == [2]
    assert collisions(x, body_diameter_m=0.0)[1].tolist() == []
    assert collisions(x[1:3], body_diameter_m=0.1)[1].tolist() == [1]  # in contact from the start
    x[2:4, 1] = np.nan  # agent 2 not recorded at epochs 2-3: its contact of 1-2 is one
    assert collisions(x, body_diameter_m=0.1)[1].tolist() == [2]


def test_safety_at_scale_equals_all_pairs() -> None:
    # the k-d tree's minimum and contacts against every pair, on a random crowd
    rng = np.random.default_rng(5)
    x = rng.uniform(0.0, 3.0, size=(4, 300, 2))
    x[1, 7] = np.nan
    dist = pair_distances(x)
    want = np.nanmin(np.where(np.isfinite(dist), dist, np.nan), axis=-1)
    np.testing.assert_array_equal(min_distance(x), want)
    pairs, counts = collisions(x, body_diameter_m=0.05)
    i, j = np.triu_indices(300, k=1)
    touch = np.where(np.isfinite(dist), dist, np.inf) < 0.05
    starts = touch & ~np.vstack([np.zeros((1, touch.shape[1]), bool), touch[:-1]])
    hit = starts.sum(axis=0)
    assert pairs.tolist() == np.c_[i + 1, j + 1][hit > 0].tolist()
    assert counts.tolist() == hit[hit > 0].tolist()


def test_time_out_of_bounds_per_agent() -> None:
    x = np.zeros((4, 2, 2))
    x[1:3, 0, 1] = 2.5  # agent 1 out for two epochs
    x[3, 1, 0] = -3.0  # agent 2 for one
    out = time_out_of_bounds(x, np.array([-2.0, -2.0]), np.array([2.0, 2.0]), period_s=0.5)
    assert out.tolist() == [1.0, 0.5]
