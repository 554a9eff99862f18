"""Consensus formation control (docs/model.md §3): convergence, the sign fix, the distance law."""

from __future__ import annotations

import numpy as np

from agent.control import displacement_command, distance_command, step_double, step_single


def triangle():  # type: ignore[no-untyped-def]
    d0 = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    links = np.array([[1, 2], [2, 1], [2, 3], [3, 2], [1, 3], [3, 1]])  # (src j, dst i)
    return d0, links


def run(x, d0, links, steps, eps=0.25, law="displacement", pin=0):  # type: ignore[no-untyped-def]
    src, dst = links[:, 0] - 1, links[:, 1] - 1
    used = np.ones(len(links), bool)
    for _ in range(steps):
        rel = x[dst] - x[src]
        if law == "displacement":
            cmd = displacement_command(len(x), dst, rel, d0[dst] - d0[src], used, eps)
        else:
            csq = np.sum((d0[dst] - d0[src]) ** 2, axis=1)
            cmd = distance_command(len(x), dst, rel, csq, used, eps)
        nxt = step_single(x, cmd, np.zeros(2), 1.0)
        nxt[pin] = x[pin]
        x = nxt
    return x


def test_displacement_converges_to_the_shape_translated_with_the_leader() -> None:
    d0, links = triangle()
    x0 = d0 + np.random.default_rng(1).normal(0, 0.3, d0.shape)
    x0[0] = [5.0, 5.0]
    x = run(x0, d0, links, 200)
    np.testing.assert_allclose(x - x[0], d0 - d0[0], atol=1e-9)
    np.testing.assert_array_equal(x[0], [5.0, 5.0])


def test_the_sign_matters_the_chapter_eq_12_diverges() -> None:
    d0, links = triangle()
    x0 = d0 + np.random.default_rng(3).normal(0, 0.1, d0.shape)
    x = run(x0, d0, links, 50, eps=-0.25)  # the chapter's sign
    assert np.linalg.norm(x - d0) > 1e3


def test_distance_law_reaches_the_distances() -> None:
    d0, links = triangle()
    x0 = d0 + np.random.default_rng(2).normal(0, 0.05, d0.shape)
    x = run(x0, d0, links, 2000, eps=0.05, law="distance")
    for a, b in [(0, 1), (1, 2), (0, 2)]:
        assert abs(np.linalg.norm(x[a] - x[b]) - np.linalg.norm(d0[a] - d0[b])) < 1e-6


def test_double_integrator_settles_at_the_shape() -> None:
    d0, links = triangle()
    src, dst = links[:, 0] - 1, links[:, 1] - 1
    x, v = d0 + 0.2, np.zeros((3, 2))
    x[0] = d0[0]
    for _ in range(400):
        cmd = displacement_command(
            3, dst, x[dst] - x[src], d0[dst] - d0[src], np.ones(6, bool), 0.25
        )
        x_new, v = step_double(x, v, cmd, np.zeros(2), 1.0, 1.0)
        x_new[0], v[0] = d0[0], 0.0
        x = x_new
    np.testing.assert_allclose(x, d0, atol=1e-6)


def test_each_agents_terms_add_in_link_order_as_np_add_at() -> None:
    rng = np.random.default_rng(5)
    n, links = 50, 400
    receivers = rng.integers(0, n, size=links)
    rel, desired = rng.normal(size=(links, 3)) * 1e2, rng.normal(size=(links, 3))
    used = rng.random(links) < 0.8
    csq = rng.random(links)
    for got, terms in (
        (displacement_command(n, receivers, rel, desired, used, 0.3), rel - desired),
        (
            distance_command(n, receivers, rel, csq, used, 0.3),
            (np.einsum("ld,ld->l", rel, rel) - csq)[:, None] * rel,
        ),
    ):
        want = np.zeros((n, 3))
        np.add.at(want, receivers, np.where(used[:, None], terms, 0.0))
        assert got.tobytes() == (-0.3 * want).tobytes()
