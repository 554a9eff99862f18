"""The batch simulator equals the one-seed simulator, member by member."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from agent import measurement_noise
from formation.errors import BatchError
from formation.scenario import STRATEGIES, Scenario
from testbed.experiments.studies import dynamic_team
from testbed.sim.batch import plan_batch, run_batch
from testbed.sim.plan import _noise
from testbed.sim.simulate import SimResult, simulate

SCENARIOS = Path(__file__).resolve().parents[3] / "scenarios"
EPOCHS = 25
FLOAT_FIELDS = (
    "positions",
    "formation_error",
    "shape_error",
    "estimates",
    "estimate_cov",
    "substitution_errors",
    "nees_values",
    "estimation_errors",
)
EXACT_FIELDS = (
    "observable",
    "delivered",
    "report_ok",
    "estimate_ok",
    "healthy",
    "tree",
    "components",
    "rigidity_rank",
    "substitution_epochs",
)


def assert_same(ref: SimResult, got: SimResult) -> None:
    for f in FLOAT_FIELDS:
        a, b = getattr(ref, f), getattr(got, f)
        assert a.shape == b.shape, f
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b), err_msg=f)
        np.testing.assert_allclose(np.nan_to_num(b), np.nan_to_num(a), rtol=0, atol=1e-9, err_msg=f)
    for f in EXACT_FIELDS:
        np.testing.assert_array_equal(getattr(got, f), getattr(ref, f), err_msg=f)
    assert got.fallbacks == ref.fallbacks
    want, have = ref.summary(), got.summary()
    assert have.keys() == want.keys()
    for key, value in want.items():
        if isinstance(value, float):
            assert have[key] == pytest.approx(value, rel=1e-9, abs=1e-12), key
        else:
            assert have[key] == value, key


def lossy_paper(paper: Scenario) -> Scenario:
    """Link 1–2 down, every other formation link and every control link lossy."""
    return paper.with_overrides(
        network={
            "formation_default": [{"model": "bernoulli", "p_loss": 0.3}],
            "links": [{"between": [1, 2], "models": [{"model": "outage", "start": 1}]}],
            "control_default": [{"model": "bernoulli", "p_loss": 0.1}],
        }
    )


@pytest.mark.parametrize("topology", ["paper-lossy", "octahedron3d", "ring8", "events"])
def test_every_strategy_equals_simulate(paper: Scenario, topology: str) -> None:
    scenario = (
        lossy_paper(paper)
        if topology == "paper-lossy"
        else Scenario.from_file(SCENARIOS / f"{topology}.toml")
    )
    if topology != "paper-lossy":
        scenario = scenario.with_overrides(
            network={"formation_default": [{"model": "bernoulli", "p_loss": 0.25}]}
        )
    # events.toml: 6 joins at 15, 3 crashes at 25 and restarts at 40, 5 leaves at 60
    epochs = scenario.epochs if topology == "events" else EPOCHS
    if topology == "events":
        team = scenario.membership
        assert team.crashed.any() and team.starts[40, 2] and not team.present[-1, 4]
    seeds = [1, 7]
    plan = plan_batch(scenario, seeds, epochs)
    for strategy in STRATEGIES:
        res = run_batch(plan, strategy)
        for b, seed in enumerate(seeds):
            assert_same(simulate(scenario, strategy, seed, epochs), res.member(b))


@pytest.mark.parametrize(
    "overrides",
    [
        {
            "network": {
                "formation_default": [
                    {"model": "bernoulli", "p_loss": 0.2},
                    {"model": "delay", "epochs": 1, "jitter_epochs": 1},
                ]
            }
        },
        {
            "estimator": {"edges": "healthy", "edge_rule": "both"},
            "network": {"formation_default": [{"model": "gilbert_elliott", "p": 0.2, "r": 0.5}]},
        },
        {
            "control": {"controller": "distance", "gain": 0.05},
            "network": {"formation_default": [{"model": "bernoulli", "p_loss": 0.3}]},
        },
        {
            "control": {"dynamics": "double", "gain": 0.1},
            "network": {"formation_default": [{"model": "bernoulli", "p_loss": 0.3}]},
        },
    ],
    ids=["delay", "healthy-both", "distance", "double"],
)
def test_model_variants_equal_simulate(paper: Scenario, overrides: dict[str, object]) -> None:
    scenario = paper.with_overrides(**overrides)
    plan = plan_batch(scenario, [3], EPOCHS)
    for strategy in ("hold", "blend", "drop"):
        assert_same(simulate(scenario, strategy, 3, EPOCHS), run_batch(plan, strategy).member(0))


def test_network_variants_share_a_batch(paper: Scenario) -> None:
    variants = [
        paper.with_overrides(network={"formation_default": [{"model": "bernoulli", "p_loss": p}]})
        for p in (0.0, 0.5)
    ]
    plan = plan_batch(variants, [2, 2], EPOCHS)
    res = run_batch(plan, "estimate")
    for b, v in enumerate(variants):
        assert_same(simulate(v, "estimate", 2, EPOCHS), res.member(b))


def test_a_member_does_not_depend_on_its_batch(paper: Scenario) -> None:
    """Bit for bit: what a resumed sweep recomputes equals what a whole sweep computes."""
    scenario = lossy_paper(paper)
    plan = plan_batch(scenario, [1, 2, 3, 4, 5], EPOCHS)
    whole = run_batch(plan, "blend", detail=False)
    alone = run_batch(plan_batch(scenario, [4], EPOCHS), "blend", detail=False)
    part = run_batch(plan.subset([3, 0]), "blend", detail=False)
    np.testing.assert_array_equal(alone.positions[:, 0], whole.positions[:, 3])
    np.testing.assert_array_equal(part.positions[:, 0], whole.positions[:, 3])
    np.testing.assert_array_equal(part.positions[:, 1], whole.positions[:, 0])


def test_members_must_share_the_structure(paper: Scenario) -> None:
    other = paper.with_overrides(control={"gain": 0.2})
    with pytest.raises(BatchError, match=r"member 1 \(paper\): differs from member 0 in control"):
        plan_batch([paper, other], [1, 1])
    with pytest.raises(BatchError, match="2 scenarios for 3 seeds"):
        plan_batch([paper, paper], [1, 2, 3])


def test_an_agent_that_leaves_or_has_not_joined_is_out_of_the_formation(paper: Scenario) -> None:
    team = dynamic_team(paper, leave=(5, 10), join=(6, 15))  # events (formation.events)
    res = run_batch(plan_batch(team, [1, 2], EPOCHS), "estimate")
    assert res.observable is not None and res.tree is not None
    x = res.positions
    np.testing.assert_array_equal(x[11:, :, 4], np.broadcast_to(x[10:11, :, 4], x[11:, :, 4].shape))
    np.testing.assert_array_equal(x[:15, :, 5], np.broadcast_to(x[0:1, :, 5], x[:15, :, 5].shape))
    assert not res.observable[10:15, :, 4:].any() and res.observable[15:, :, 5].all()
    assert (res.tree[5].sum(axis=1) == 4).all() and (res.tree[12].sum(axis=1) == 3).all()
    assert (res.tree[20].sum(axis=1) == 4).all()
    assert (res.sub_link < 2 * len(team.edge_array)).all()


def test_the_team_errors_count_the_edges_between_agents_taking_part() -> None:
    """An agent that left stands still while the team moves on: its edges are not the team's."""
    scenario = Scenario.from_file(SCENARIOS / "events.toml")  # agent 5 leaves at 60 of 80
    res = run_batch(plan_batch(scenario, [1, 2], scenario.epochs), "estimate", detail=False)
    formation, shape = res.team_errors()
    edges, x = scenario.edge_array, res.positions[-1]  # (B, n, d) at the last epoch
    kept = (edges != 5).all(axis=1)  # edges 3-5 and 4-5 are gone with agent 5
    i, j = edges[kept, 0] - 1, edges[kept, 1] - 1
    d0 = scenario.offsets
    want = np.sqrt(np.mean(np.sum((x[:, i] - x[:, j] - (d0[i] - d0[j])) ** 2, axis=-1), axis=-1))
    np.testing.assert_allclose(shape[-1], want, rtol=1e-12)
    gap = np.linalg.norm(x[:, i] - x[:, j], axis=-1) - scenario.weights[kept]
    np.testing.assert_allclose(formation[-1], np.sqrt(np.mean(gap**2, axis=-1)), rtol=1e-12)
    assert (shape[-1] < 0.05).all() and (res.shape_error[-1] > 0.05).all()
    assert (res.shape_error[:15] > shape[:15]).all()  # agent 6 waits below edge 3-4 until it joins
    # With everyone there (epochs 40-59) every edge counts; without events the arrays are the
    # batch's own.
    np.testing.assert_array_equal(shape[40:60], res.shape_error[40:60])
    np.testing.assert_array_equal(formation[40:60], res.formation_error[40:60])
    plain = run_batch(plan_batch(scenario.with_overrides(events=[]), [1], 20), "hold", detail=False)
    assert plain.team_errors()[0] is plain.formation_error
    assert plain.team_errors()[1] is plain.shape_error


def test_noise_drawn_a_block_of_epochs_at_a_time_is_the_whole_runs(paper: Scenario) -> None:
    src, dst = paper.directed_links[:, 0], paper.directed_links[:, 1]
    cov = paper.noise_covariance
    whole = measurement_noise(cov, 5, dst[None, :], src[None, :], np.arange(7)[:, None])
    two_epochs = 2 * src.size * cov.shape[0] + 1  # blocks of 2, 2, 2 and 1 epochs
    blocks = _noise(cov, np.array([5, 6]), src, dst, 7, draws=two_epochs)
    assert blocks[0].tobytes() == whole.tobytes()
    assert not np.array_equal(blocks[1], whole)  # the other seed's own draws
