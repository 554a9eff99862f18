"""``critical.md`` and ``success.md`` open with sentences computed from the sweep's numbers."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from formation.scenario import Scenario
from testbed.experiments.grid import critical
from testbed.experiments.sweep import SweepSpec, SweepSummary, conclusion, write_tables

LOSSES = (0.0, 0.1, 0.2, 0.3)


def summary_of(paper: Scenario, success: dict[str, list[float]]) -> SweepSummary:
    spec = SweepSpec(
        topologies=(("paper", paper),),
        losses=LOSSES,
        strategies=tuple(success),  # type: ignore[arg-type]
        seeds=(1, 2),
    )
    got = {("paper", "bernoulli", s): np.array(v) for s, v in success.items()}
    nan = np.full(len(LOSSES), np.nan)
    return SweepSummary(
        spec,
        got,
        {k: nan for k in got},
        {("paper", "bernoulli"): np.array(LOSSES)},
        {k: critical(LOSSES, v, easiest="low") for k, v in got.items()},
    )


def test_the_opening_says_who_tolerates_most_loss_and_who_coincides(paper: Scenario) -> None:
    said = conclusion(
        summary_of(
            paper, {"hold": [1, 1, 0, 0], "estimate": [1, 1, 1, 0.5], "blend": [1, 1, 1, 0.5]}
        )
    )
    assert said == (
        "In **paper, bernoulli**, the formation is kept in ≥ 95% of the seeds at every loss "
        "rate up to 0.2 (`estimate`, `blend`) and up to 0.1 (`hold`); `estimate` and `blend` "
        "keep the same share at every point."
    )
    other = conclusion(
        summary_of(paper, {"hold": [1, 1, 1, 1], "estimate": [1, 1, 1, 0.5], "blend": [0, 0, 0, 0]})
    )
    assert other == (
        "In **paper, bernoulli**, the formation is kept in ≥ 95% of the seeds at every loss "
        "rate up to 0.3 (`hold`), up to 0.2 (`estimate`) and nowhere on the grid (`blend`)."
    )


def test_both_tables_open_with_it(paper: Scenario, tmp_path: Path) -> None:
    summary = summary_of(paper, {"hold": [1, 0, 0, 0], "estimate": [1, 1, 0, 0]})
    write_tables(summary, tmp_path)
    said = conclusion(summary)
    for name in ("critical.md", "success.md"):
        lines = (tmp_path / name).read_text().splitlines()
        assert lines[1:3] == ["", said], name
