"""Unicycle dynamics through the near-identity transform: tracking, limits, saturation counts."""

from __future__ import annotations

import numpy as np
import pytest

from agent.control import displacement_command, step_unicycle

LIMITS = (0.2, 3.6, 0.05, 20)  # a small ground robot: v, ω, look-ahead, inner steps


def centres(p: np.ndarray, th: np.ndarray, look: float = 0.05) -> np.ndarray:
    return p - look * np.stack([np.cos(th), np.sin(th)], axis=1)


def test_the_look_ahead_point_follows_a_slow_command() -> None:
    rng = np.random.default_rng(1)
    p, th = rng.normal(size=(6, 2)), rng.uniform(-np.pi, np.pi, 6)
    u = 0.05 * rng.normal(size=(6, 2))  # [m/s], well under the limits once turned
    p2, _, _ = step_unicycle(p, th, u * 1.0, np.zeros((6, 2)), 1.0, (0.2, 3.6, 0.05, 200))
    # exact in continuous time; the zero-order hold over 1/200 s sub-steps leaves a small error
    np.testing.assert_allclose(p2, p + u, atol=2e-3)


def test_a_straight_command_along_the_heading_moves_straight() -> None:
    p, th = np.zeros((1, 2)), np.zeros(1)
    p2, th2, sat = step_unicycle(p, th, np.array([[0.1, 0.0]]), np.zeros((1, 2)), 1.0, LIMITS)
    np.testing.assert_allclose(p2, [[0.1, 0.0]], atol=1e-15)
    assert th2.tolist() == [0.0] and sat.tolist() == [0]


def test_speeds_never_exceed_the_limits_and_saturation_is_counted() -> None:
    rng = np.random.default_rng(2)
    p, th = rng.normal(size=(8, 2)), rng.uniform(-np.pi, np.pi, 8)
    big = 3.0 * rng.normal(size=(8, 2))  # [m] asked in one epoch: far over 0.2 m/s
    steps = LIMITS[3]
    p2, th2, sat = step_unicycle(p, th, big, np.zeros((8, 2)), 1.0, LIMITS)
    travelled = np.linalg.norm(centres(p2, th2) - centres(p, th), axis=1)
    assert (travelled <= LIMITS[0] * 1.0 + 1e-12).all()  # a chord is no longer than its arc
    turned = np.abs(np.angle(np.exp(1j * (th2 - th))))
    assert (turned <= LIMITS[1] * 1.0 + 1e-12).all()
    assert (sat > 0).all() and (sat <= steps).all()
    calm, _, none = step_unicycle(p, th, np.zeros((8, 2)), np.zeros((8, 2)), 1.0, LIMITS)
    np.testing.assert_allclose(calm, p, atol=1e-15)
    assert none.tolist() == [0] * 8


def test_headings_are_wrapped() -> None:
    p, th = np.zeros((1, 2)), np.array([3.1])
    _, th2, _ = step_unicycle(p, th, np.array([[0.0, 0.05]]), np.zeros((1, 2)), 1.0, LIMITS)
    assert -np.pi <= th2[0] < np.pi


def test_one_agent_equals_the_team_bit_for_bit() -> None:
    rng = np.random.default_rng(3)
    p, th, cmd = rng.normal(size=(5, 2)), rng.uniform(-np.pi, np.pi, 5), rng.normal(size=(5, 2))
    vref = np.zeros((5, 2))
    team = step_unicycle(p, th, cmd, vref, 1.0, LIMITS)
    for i in range(5):
        one = step_unicycle(
            p[i : i + 1], th[i : i + 1], cmd[i : i + 1], vref[i : i + 1], 1.0, LIMITS
        )
        assert one[0].tolist() == team[0][i : i + 1].tolist()
        assert one[1].tolist() == team[1][i : i + 1].tolist()


@pytest.mark.parametrize(("gain", "saturates"), [(0.05, False), (0.45, True)])
def test_a_team_converges_within_its_limits_and_a_high_gain_saturates(
    gain: float, saturates: bool
) -> None:
    # a triangle, all links delivered, the displacement law on the look-ahead points
    d0 = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, 0.8]])
    links = np.array([[0, 1], [1, 0], [0, 2], [2, 0], [1, 2], [2, 1]])
    rng = np.random.default_rng(4)
    p = d0 + 0.1 * rng.normal(size=(3, 2))
    th = rng.uniform(-np.pi, np.pi, 3)
    sat_total = 0
    for _ in range(400):
        rel = p[links[:, 1]] - p[links[:, 0]]
        desired = d0[links[:, 1]] - d0[links[:, 0]]
        cmd = displacement_command(3, links[:, 1], rel, desired, np.ones(6, bool), gain)
        p, th, sat = step_unicycle(p, th, cmd, np.zeros((3, 2)), 1.0, LIMITS)
        sat_total += int(sat.sum())
    shape = (p - p.mean(axis=0)) - (d0 - d0.mean(axis=0))
    assert np.abs(shape).max() < 1e-3
    assert (sat_total > 0) == saturates
