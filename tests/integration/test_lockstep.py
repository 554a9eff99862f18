"""The distributed lockstep runtime: real processes over Zenoh on 127.0.0.1."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from formation.scenario import STRATEGIES, Scenario
from testbed.runtime.launcher import launch
from testbed.sim.simulate import simulate

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
    missing = sorted(set(expected) - set(verdicts))
    assert verdicts == expected, (  # which records did not come, and was something unreadable
        f"{len(missing)} records missing, epochs {missing[0][2] if missing else '-'}.."
        f"{missing[-1][2] if missing else '-'}; malformed {outcome.malformed}"
    )
    assert sum(not v for v in verdicts.values()) == 2 * (
        paper.epochs - 1
    )  # link 1-2 down from epoch 1
    assert outcome.malformed == {}
    # Every packet's record, also those of the clean report and estimate phases, which netem
    # publishes in batches: the last batch must not trail the run's end.
    assert Counter(d.link_class for d in outcome.decisions) == {
        "formation": len(links) * paper.epochs,
        "report": paper.n * paper.epochs,
        "estimate": paper.n * paper.epochs,
    }
    # The substitutions the agents report equal the simulator's, in (epoch, receiver, sender) order.
    order = np.lexsort(
        (
            sim.substitutions.neighbour,
            sim.substitutions.agent,
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
    # The full path: delayed packets delivered with a later epoch, duplicates, control loss.
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


def test_clean_and_unclean_epochs_mixed_equal_the_simulator(
    paper: Scenario, runs_dir: Path
) -> None:
    # netem decides a packet on all its links from its stream's row (netem.proxy.decision_rows);
    # here epochs in which every link passes alternate with an outage window, delays that deliver
    # a held packet into an otherwise clean epoch, and control-link loss.
    scenario = paper.with_overrides(
        epochs=40,
        network={
            "links": [
                {"between": [1, 2], "models": [{"model": "outage", "start": 10, "end": 15}]},
                {"between": [3, 5], "direction": "forward",
                 "models": [{"model": "delay", "epochs": 0, "jitter_epochs": 1}]},
            ],
            "control": [{"agent": 4, "direction": "report",
                         "models": [{"model": "bernoulli", "p_loss": 0.2}]}],
        },
    )  # fmt: skip
    outcome = launch(scenario, strategy="hold", runs_dir=runs_dir, record=False)
    sim = simulate(scenario, strategy="hold")
    np.testing.assert_allclose(outcome.positions, sim.positions, rtol=0, atol=1e-9)
    expected = {
        (int(a), int(b), k): bool(sim.delivered[k, row])
        for k in range(scenario.epochs)
        for row, (a, b) in enumerate(scenario.directed_links)
    }
    assert formation_verdicts(outcome) == expected
    # One record per packet: every link of every phase, every epoch, exactly once.
    counts = Counter((d.link_class, d.source, d.target, d.epoch) for d in outcome.decisions)
    links = len(scenario.directed_links) + 2 * scenario.n
    assert len(counts) == links * scenario.epochs
    assert set(counts.values()) == {1}
    verdicts = Counter(d.verdict for d in outcome.decisions)
    assert verdicts["pass"] > 0 and verdicts["drop"] > 0 and verdicts["delayed"] > 0
    # Every packet netem passed went out once, and every delayed one (by one epoch) went out
    # with the next epoch's delivery, also when that epoch was otherwise clean.
    due: Counter[str] = Counter()
    for d in outcome.decisions:
        if d.link_class == "formation" and (
            d.verdict == "pass" or (d.verdict == "delayed" and d.epoch + 1 < scenario.epochs)
        ):
            due[f"link/{d.source}/{d.target}/state"] += 1
    forwarded = {k.split("/", 2)[2]: v for k, v in outcome.delivered.items() if "/link/" in k}
    assert {k: v for k, v in forwarded.items() if k.endswith("/state")} == dict(due)
    # ... in one delivery per receiver, phase and epoch.
    deliveries = {k.split("/", 2)[2]: v for k, v in outcome.sent.items() if "/inbox/" in k}
    assert deliveries == {
        **{f"inbox/{j}/{phase}": scenario.epochs for j in range(1, scenario.n + 1)
           for phase in ("state", "estimate")},
        "inbox/0/report": scenario.epochs,
    }  # fmt: skip
