"""The distributed lockstep runtime: real processes over Zenoh on 127.0.0.1."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from formation.scenario import STRATEGIES, Scenario
from testbed.launcher import launch
from testbed.simulate import simulate

pytestmark = pytest.mark.integration


def formation_verdicts(outcome) -> dict[tuple[int, int, int], bool]:  # type: ignore[no-untyped-def]
    return {
        (d.source, d.target, d.epoch): d.verdict in ("pass", "duplicate")
        for d in outcome.decisions
        if d.link_class == "formation"
    }


@pytest.mark.parametrize("strategy", STRATEGIES)
def test_lockstep_run_equals_the_simulator(paper: Scenario, runs_dir: Path, strategy: str) -> None:
    outcome = launch(paper, strategy=strategy, runs_dir=runs_dir, record=False)  # type: ignore[arg-type]
    sim = simulate(paper, strategy=strategy)  # type: ignore[arg-type]
    assert np.isfinite(outcome.positions).all()
    np.testing.assert_allclose(outcome.positions, sim.positions, rtol=0, atol=1e-9)
    verdicts = formation_verdicts(outcome)
    links = paper.directed_links
    expected = {
        (int(a), int(b), k): bool(sim.delivered[k, row])
        for k in range(paper.epochs)
        for row, (a, b) in enumerate(links)
    }
    assert verdicts == expected
    assert sum(not v for v in verdicts.values()) == 2 * (
        paper.epochs - 1
    )  # link 1-2 down from epoch 1
    assert outcome.malformed == {}
    # The substitutions the agents report equal the simulator's, in (epoch, receiver, sender) order.
    order = np.lexsort(
        (
            sim.extra["substitution_senders"],
            sim.extra["substitution_receivers"],
            sim.substitution_epochs,
        )
    )
    np.testing.assert_allclose(
        outcome.substitution_errors(), sim.substitution_errors[order], rtol=0, atol=1e-9
    )


def lossy(paper: Scenario) -> Scenario:
    return paper.with_overrides(
        network={"formation_default": [{"model": "bernoulli", "p_loss": 0.3}]},
        epochs=30,
    )


def test_same_seed_same_run_different_seed_different_run(paper: Scenario, runs_dir: Path) -> None:
    scenario = lossy(paper)
    a = launch(scenario, seed=3, runs_dir=runs_dir, record=False)
    b = launch(scenario, seed=3, runs_dir=runs_dir, record=False)
    c = launch(scenario, seed=4, runs_dir=runs_dir, record=False)
    np.testing.assert_array_equal(a.positions, b.positions)
    assert formation_verdicts(a) == formation_verdicts(b)
    assert not np.allclose(a.positions, c.positions)
    assert formation_verdicts(a) != formation_verdicts(c)
    np.testing.assert_allclose(a.positions, simulate(scenario, seed=3).positions, rtol=0, atol=1e-9)


@pytest.mark.parametrize("strategy", ["hold", "estimate"])
def test_delays_duplicates_and_control_loss_equal_the_simulator(
    paper: Scenario, runs_dir: Path, strategy: str
) -> None:
    # The paths where netem must send a close although every packet arrived (a delayed
    # packet delivered with a later epoch, a duplicate) and where it needs none.
    scenario = paper.with_overrides(
        epochs=40,
        network={
            "formation_default": [
                {"model": "bernoulli", "p_loss": 0.15},
                {"model": "delay", "epochs": 0, "jitter_epochs": 1},
                {"model": "duplicate", "p": 0.2},
            ],
            "control_default": [{"model": "bernoulli", "p_loss": 0.1}],
        },
    )
    outcome = launch(scenario, strategy=strategy, runs_dir=runs_dir, record=False)  # type: ignore[arg-type]
    sim = simulate(scenario, strategy=strategy)  # type: ignore[arg-type]
    np.testing.assert_allclose(outcome.positions, sim.positions, rtol=0, atol=1e-9)
    verdicts = {d.verdict for d in outcome.decisions}
    assert {"pass", "drop", "delayed", "duplicate"} <= verdicts
