"""The distance controller's stable step (docs/model.md §3): refused at load above the bound."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from agent.control import distance_command, step_single
from formation.errors import ScenarioError
from formation.rigidity import distance_epsilon_bound
from formation.scenario import Scenario, load
from testbed.sim.simulate import simulate

PAPER = Path(__file__).resolve().parents[3] / "scenarios" / "paper.toml"


def distance_paper(tmp_path: Path, gain: float) -> Path:
    text = PAPER.read_text().replace('controller = "displacement"', 'controller = "distance"')
    path = tmp_path / "paper.toml"
    path.write_text(re.sub(r"gain = 0\.25 .*", f"gain = {gain}", text))
    return path


def test_the_paper_s_gain_is_refused_for_the_distance_controller_naming_the_bound(
    tmp_path: Path,
) -> None:
    with pytest.raises(
        ScenarioError,
        match=r"paper\.toml: control\.gain = 0\.25; epsilon = gain \* period_s = 0\.25 must be "
        r"< 0\.0985 = 1/lambda_max .* \(gain < 0\.0985\)",
    ):
        load(distance_paper(tmp_path, 0.25))


def test_a_gain_under_the_bound_loads_and_keeps_the_edge_lengths(tmp_path: Path) -> None:
    s = load(distance_paper(tmp_path, 0.05)).with_overrides(epochs=300)
    assert np.isfinite(simulate(s, "estimate").formation_error).all()
    assert simulate(s, "estimate").formation_error[-1] < 0.01


def gradient_steps(d0: np.ndarray, edges: np.ndarray, eps: float, steps: int) -> np.ndarray:
    """The distance law on every edge both ways, agent 1 pinned, from the shape nudged."""
    links = np.concatenate([edges, edges[:, ::-1]]) - 1
    src, dst = links[:, 0], links[:, 1]
    csq = np.sum((d0[dst] - d0[src]) ** 2, axis=1)
    x = d0 + 1e-6 * np.random.default_rng(1).standard_normal(d0.shape)
    for _ in range(steps):
        cmd = distance_command(len(x), dst, x[dst] - x[src], csq, np.ones(len(src), bool), eps)
        x = np.vstack([x[:1], step_single(x, cmd, np.zeros(2), 1.0)[1:]])
    return x


def test_the_bound_is_where_the_shape_turns_unstable(paper: Scenario) -> None:
    d0, edges = paper.offsets, paper.edge_array
    bound = distance_epsilon_bound(d0, edges, pinned=1)

    def lengths(x: np.ndarray) -> np.ndarray:
        return np.linalg.norm(x[edges[:, 0] - 1] - x[edges[:, 1] - 1], axis=1)

    below = gradient_steps(d0, edges, 0.98 * bound, 2000)
    above = gradient_steps(d0, edges, 1.02 * bound, 2000)
    np.testing.assert_allclose(lengths(below), lengths(d0), atol=1e-9)
    assert not np.allclose(lengths(above), lengths(d0), atol=1e-3)


def test_large_frameworks_get_the_same_bound_by_lanczos() -> None:
    rng = np.random.default_rng(2)
    n = 302  # n d = 604 columns: past the dense path
    x = rng.uniform(0, 10, (n, 2))
    edges = np.array([(i, i + 1) for i in range(1, n)] + [(i, i + 2) for i in range(1, n - 1)])
    big = distance_epsilon_bound(x, edges, pinned=1)
    small = distance_epsilon_bound(x[:200], edges[(edges <= 200).all(axis=1)], pinned=1)
    r = np.zeros((len(edges), 2 * n))
    for k, (i, j) in enumerate(edges - 1):
        r[k, 2 * i : 2 * i + 2], r[k, 2 * j : 2 * j + 2] = x[i] - x[j], x[j] - x[i]
    dense = 1.0 / np.linalg.eigvalsh((r.T @ r)[2:, 2:])[-1]
    assert big == pytest.approx(dense, rel=1e-9)
    # fewer edges, a smaller Hessian: a bound no lower, equal where the top mode lies in the
    # first 200 agents (here), so compared to rounding (dense and Lanczos differ by an ulp)
    assert small >= big * (1 - 1e-12)
