"""``formation experiment value``'s files, and its real-process check of one case per region."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pandas as pd

from testbed.experiments.grid import write_cells
from testbed.experiments.real_check import real_run_row
from testbed.experiments.value import COLUMNS, KEEP_M, ValueSpec, shaped
from testbed.experiments.value_plot import plot_value_map
from testbed.experiments.value_report import results_markdown, rows, verdict

FIGURE = "value.png"
CHECKED = ("estimate", "drop")  # the strategies each region's real run compares


def run_value_real(
    frame: pd.DataFrame,
    spec: ValueSpec,
    out: Path,
    record: bool = True,
    log: Callable[[str], None] = print,
) -> list[dict[str, Any]]:
    """The first row of each region, estimate and drop at the first seed, as real processes in
    lockstep: each a row saying whether its positions equal the simulator's to the bit."""
    firsts: dict[str, Any] = {}
    for r in rows(frame, spec):
        firsts.setdefault(verdict(r), r)
    by_label = {c.label: c for c in spec.cases}
    checked = []
    for region, r in firsts.items():
        case = by_label[r.case]
        scenario = shaped(spec.scenario, case.shape, r.controller, spec.epochs)
        scenario = scenario.with_overrides(network=case.network)
        for strategy in CHECKED:
            log(f"value, real processes: {r.controller}, {r.case}, {strategy} …")
            row = {"controller": r.controller, "case": r.case, "region": region}
            row |= {"strategy": strategy, "seed": spec.seeds[0]}
            checked.append(
                real_run_row(scenario, strategy, spec.seeds[0], out / "runs", record, row)
            )
    return checked


def write_outputs(
    frame: pd.DataFrame, spec: ValueSpec, out: Path, real: list[dict[str, Any]]
) -> None:
    """``runs.csv`` (a row per cell), ``results.md`` and the figure in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    write_cells(out / "runs.csv", frame.to_dict("records"), COLUMNS)
    plot_value_map(rows(frame, spec), spec.strategies, spec.controllers, KEEP_M, out / FIGURE)
    (out / "results.md").write_text(results_markdown(frame, spec, FIGURE, real))


__all__ = ["FIGURE", "run_value_real", "write_outputs"]
