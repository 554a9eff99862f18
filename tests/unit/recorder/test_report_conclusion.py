"""report.md opens with sentences computed from the runs: they change when the runs do."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from formation.scenario import Scenario
from recorder.reporting.conclusion import conclusion, evidence, keep_sentence
from recorder.reporting.report import write_report_from
from testbed.sim.simulate import simulate
from testkit.report_files import missing

ROOT = Path(__file__).resolve().parents[3]
STRATEGIES = ("zero", "hold", "estimate", "blend", "drop")


def _down(paper: Scenario, pairs: list[tuple[int, int]]) -> Scenario:
    """``paper`` with the links ``pairs`` down in both directions from epoch 1."""
    net = paper.network.model_dump(by_alias=True)
    net["links"] = [
        {"between": list(p), "direction": "both", "models": [{"model": "outage", "start": 1}]}
        for p in pairs
    ]
    return paper.with_overrides(network=net)


@pytest.fixture(scope="module")
def paper() -> Scenario:
    return Scenario.from_file(ROOT / "scenarios" / "paper.toml")


def _records(scenario: Scenario) -> list[Any]:
    return [simulate(scenario, s).record() for s in STRATEGIES]


def test_the_paper_s_estimate_and_blend_coincide_because_the_far_end_is_the_reference(
    paper: Scenario, tmp_path: Path
) -> None:
    runs = _records(paper)
    text = " ".join(conclusion(runs))
    assert text.startswith("`estimate`, `blend` and `drop` keep the formation")
    assert "`hold` and `zero` lose it" in text
    assert "`estimate` and `blend` move identically, to the bit: every lost packet an agent " \
        "steered by was agent 1's, the reference agent" in text  # fmt: skip
    assert "fell back" not in text
    assert (
        "`drop` converges: it steers by the healthy links alone, and the healthy graph was "
        "connected in every epoch, which is all displacement consensus needs (it was not "
        "rigid in 49 of 50" in text
    )
    report = write_report_from(runs, tmp_path)
    lines = report.read_text().splitlines()
    assert lines[0] == "# paper: zero, hold, estimate, blend and drop compared, seed 1"
    assert lines[2] == text  # the conclusion opens the report, then its figure and caption
    assert lines[4] == "![Formation and shape error](errors.png)"
    assert "`blend` is drawn over `estimate`: identical to the bit" in lines[6]
    assert "| epochs not rigid [3] |" in report.read_text()
    assert "[3] epochs whose healthy graph (the links that delivered) is not rigid: only the " \
        "distance controller needs rigidity" in report.read_text()  # fmt: skip
    assert missing(report, ROOT) == []


def test_an_agent_cut_off_makes_estimate_fall_back_and_drop_fail(paper: Scenario) -> None:
    runs = _records(_down(paper, [(1, 2), (3, 5), (4, 5)]))
    facts = {r.strategy: evidence(r) for r in runs}
    assert facts["estimate"].fallbacks == 98 and facts["estimate"].unobservable == {5: 49}
    text = " ".join(conclusion(runs))
    assert text.startswith("No strategy keeps the formation")
    assert "move identically" not in text  # estimate and blend part once the estimate is missing
    assert (
        "`estimate` and `blend` fell back to hold 98 times each: the leader could not observe "
        "agent 5 in 49 of 50 epochs" in text
    )
    assert "`drop` does not converge" in text
    assert (
        "split in 49 of 50 epochs and connected in the others; displacement consensus needs it connected"
        in text
    )


def test_two_lossy_links_part_estimate_and_blend(paper: Scenario) -> None:
    """Link 3–5 lossy too: agent 5 fills in agent 3, which the leader estimates with noise."""
    net = paper.network.model_dump(by_alias=True)
    net["links"] = [
        {"between": list(p), "models": [{"model": "bernoulli", "p_loss": 0.5}]}
        for p in [(1, 2), (3, 5)]
    ]
    runs = _records(paper.with_overrides(network=net))
    text = " ".join(conclusion(runs))
    assert "move identically" not in text
    estimate = evidence(runs[STRATEGIES.index("estimate")])
    assert 0 < estimate.exact < estimate.steering  # only agent 1's packets are filled exactly


def test_the_distance_controller_needs_rigidity(paper: Scenario) -> None:
    control = {**paper.control.model_dump(), "controller": "distance", "gain": 0.05}
    run = simulate(paper.with_overrides(control=control), "drop").record()
    text = " ".join(conclusion([run]))
    assert "the healthy graph was not rigid in 49 of 50 epochs and rigid in the others (connected " \
        "in every epoch); the distance controller needs it rigid" in text  # fmt: skip


def test_one_run_or_one_loser_is_named_in_the_singular() -> None:
    assert keep_sentence([("hold", 0.1)]) == (
        "`hold` loses the formation (final formation error 0.1 m, over the 0.05 m threshold)."
    )
    assert keep_sentence([("estimate", 0.005), ("zero", 0.3)]) == (
        "`estimate` keeps the formation (final formation error 0.005 m, under the 0.05 m "
        "threshold); `zero` loses it (0.3 m: 60× `estimate`'s)."
    )
