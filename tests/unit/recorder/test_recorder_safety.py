"""Safety counts: minimum inter-agent distance, collisions per pair, time out of the box."""

from __future__ import annotations

import numpy as np

from recorder.analysis.metrics import collisions, min_distance, pair_distances, time_out_of_bounds


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
    assert pairs.tolist() == [[1, 2], [1, 3], [2, 3]]
    assert counts.tolist() == [2, 0, 0]
    assert collisions(x, body_diameter_m=0.0)[1].tolist() == [0, 0, 0]
    assert collisions(x[1:3], body_diameter_m=0.1)[1].tolist() == [
        1,
        0,
        0,
    ]  # in contact from the start


def test_time_out_of_bounds_per_agent() -> None:
    x = np.zeros((4, 2, 2))
    x[1:3, 0, 1] = 2.5  # agent 1 out for two epochs
    x[3, 1, 0] = -3.0  # agent 2 for one
    out = time_out_of_bounds(x, np.array([-2.0, -2.0]), np.array([2.0, 2.0]), period_s=0.5)
    assert out.tolist() == [1.0, 0.5]
