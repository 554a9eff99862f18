"""A grid experiment: scenario variants × seeds, each run with every strategy, a row per cell.

The sweep (loss rate), ``wireless`` (radio range) and ``capacity`` (a queue's rate) ask one
question: along a grid of one parameter, up to where does each strategy keep the formation?
An experiment names its variants (a scenario and the key columns it is known by) and its
judge (what it measures of a batch); :func:`run_grid` plans the variants × seeds once (the
noise and the schedules do not depend on the strategy), runs every strategy on the plan and
returns a tidy frame. :func:`over_grid` reduces it per grid point (the fraction of seeds
kept), :func:`critical` finds the critical value, and :func:`write_outputs` writes
``runs.csv``, ``critical.md``, ``results.md`` and ``phase.png``.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt
import pandas as pd

from formation.markdown import table
from formation.scenario import Scenario, StrategyName
from testbed.experiments.plots import plot_range_phase
from testbed.sim.batch import BatchResult, plan_batch, run_batch
from testbed.sim.plan import BatchPlan

Array = npt.NDArray[Any]
KEEP_FRACTION = 0.95  # a grid point is kept when this share of its seeds keeps the formation

# What an experiment measures: column → (B,) values, one per member of the batch or plan.
Judge = Callable[[BatchResult], dict[str, Array]]
PlanMeasure = Callable[[BatchPlan], dict[str, Array]]


@dataclass(frozen=True)
class Variant:
    """A point of the grid: the columns it is known by in the frame, and the scenario it runs."""

    keys: dict[str, Any]
    scenario: Scenario


def run_grid(
    variants: Sequence[Variant],
    seeds: Sequence[int],
    strategies: Sequence[StrategyName],
    judge: Judge,
    *,
    planned: PlanMeasure | None = None,
    epochs: int | None = None,
    skip: Callable[[Variant, StrategyName, int], bool] | None = None,
    log: Callable[[StrategyName], None] | None = None,
) -> pd.DataFrame:
    """Every variant × seed with every strategy on the batch simulator; a row per cell.

    Parameters
    ----------
    variants : the grid's points, planned together (one plan, every strategy runs on it)
    judge : column → (B,) measured of a strategy's batch (its members, in order)
    planned : column → (B,) measured of the plan (the same for every strategy)
    epochs : the runs' length (default: each scenario's)
    skip : cells not to run (a resumed sweep's), by variant, strategy and seed
    log : called with each strategy before it runs

    Returns
    -------
    A frame of the variants' key columns, ``strategy``, ``seed`` and the measured columns,
    ordered by strategy, then variant, then seed.
    """
    members = [(v, seed) for v in variants for seed in seeds]
    plan = plan_batch([v.scenario for v, _ in members], [s for _, s in members], epochs)
    of_plan = {} if planned is None else planned(plan)
    frames = []
    for strategy in strategies:
        todo = [
            b for b, (v, seed) in enumerate(members) if skip is None or not skip(v, strategy, seed)
        ]
        if not todo:
            continue
        if log is not None:
            log(strategy)
        sub = plan if len(todo) == len(members) else plan.subset(todo)
        with np.errstate(all="ignore"):  # a diverging run is a lost formation, not an error
            judged = judge(run_batch(sub, strategy, detail=False))
        cells: dict[str, Any] = {
            key: [members[b][0].keys[key] for b in todo] for key in variants[0].keys
        }
        cells["strategy"] = [strategy] * len(todo)
        cells["seed"] = [members[b][1] for b in todo]
        cells.update(judged)
        cells.update({k: np.asarray(v)[todo] for k, v in of_plan.items()})
        frames.append(pd.DataFrame(cells))
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def progress(log: Callable[[str], None], prefix: str) -> Callable[[str], None]:
    """A ``log`` for :func:`run_grid`: ``"<prefix>, <strategy> …"`` before each strategy."""
    return lambda strategy: log(f"{prefix}, {strategy} …")


def over_grid(
    frame: pd.DataFrame,
    keys: Sequence[str],
    grid: str,
    points: Sequence[Any],
    value: Callable[[pd.DataFrame], float],
) -> dict[Any, Array]:
    """Per value of ``keys`` (a tuple, or the value for one key): ``value`` of its cells at
    each of the ``grid`` column's ``points`` (R,), NaN where it has none."""
    out: dict[Any, Array] = {}
    for key, part in frame.groupby(list(keys) if len(keys) > 1 else keys[0], sort=False):
        at = dict(iter(part.groupby(grid, sort=False)))
        out[key] = np.array([value(at[p]) if p in at else math.nan for p in points])
    return out


def kept_fraction(cells: pd.DataFrame) -> float:
    """The share of ``cells`` whose ``kept`` column is true."""
    return float(np.mean(cells["kept"].to_numpy()))


def critical(
    points: Sequence[float],
    success: Array,
    *,
    easiest: Literal["low", "high"],
    keep: float = KEEP_FRACTION,
) -> float | None:
    """The grid point up to which every point from the ``easiest`` end keeps (success ≥
    ``keep``): the largest such loss rate (``low``), the least such range or capacity
    (``high``); None when even the easiest point does not keep."""
    pairs = list(zip(points, np.asarray(success).tolist(), strict=True))
    best = None
    for p, frac in pairs if easiest == "low" else reversed(pairs):
        if not frac >= keep:
            break
        best = p
    return best


@dataclass(kw_only=True)
class GridResult:
    """A grid experiment's cells and verdicts.

    frame : a row per cell (:func:`run_grid`); strategies : its strategies, in order
    points : the grid (ρ); columns : the labels of the critical table's columns (a study, a case)
    success, critical : (column label, strategy) → (R,) fraction of seeds kept / the
    critical grid point (None: not even at the easiest)
    real : a row per real-process check
    """

    frame: pd.DataFrame
    strategies: tuple[StrategyName, ...]
    points: tuple[float, ...]
    columns: tuple[str, ...]
    success: dict[tuple[str, str], Array]
    critical: dict[tuple[str, str], float | None]
    real: list[dict[str, Any]] = field(default_factory=list)

    @property
    def rows(self) -> list[dict[str, Any]]:
        """The cells as dicts of Python values."""
        return list(self.frame.to_dict("records"))

    def critical_markdown(self) -> str:
        """The critical grid point per strategy (rows) and column label (columns)."""
        return table(
            ["strategy", *self.columns],
            ([s, *(_times(self.critical[(c, s)]) for c in self.columns)] for s in self.strategies),
        )

    def success_markdown(
        self, label: str, cell: Callable[[str, str, int], str] | None = None
    ) -> str:
        """Per grid point ρ (rows) and strategy: ``cell(label, strategy, i)``, by default the
        fraction of seeds that kept the formation in column ``label``."""
        cell = cell or (lambda c, s, i: f"{self.success[(c, s)][i]:.2f}")
        rows = (
            [f"{p:g}", *(cell(label, s, i) for s in self.strategies)]
            for i, p in enumerate(self.points)
        )
        return table(["ρ", *self.strategies], rows)

    def conclusion(
        self,
        quantity: str,
        easiest: Literal["low", "high"],
        written: Callable[[float], str] = lambda p: f"{p:g} ×",
    ) -> list[str]:
        """A sentence per column: where each strategy keeps the formation, the widest region
        first (``quantity`` names the grid, "radio range ρ"; ``written`` writes a grid point),
        and the strategies whose success is the same at every point."""
        out = []
        side = "from" if easiest == "high" else "up to"
        for c in self.columns:
            by_point: dict[float, list[str]] = {}
            never = []
            for s in self.strategies:
                point = self.critical[(c, s)]
                if point is None:
                    never.append(f"`{s}`")
                else:
                    by_point.setdefault(point, []).append(f"`{s}`")
            order = sorted(by_point, reverse=easiest == "low")
            parts = [f"{side} {written(p)} ({', '.join(by_point[p])})" for p in order]
            if never:
                parts.append(f"nowhere on the grid ({', '.join(never)})")
            listed = ", ".join(parts[:-1]) + " and " + parts[-1] if len(parts) > 1 else parts[0]
            text = (
                f"In **{c}**, the formation is kept in ≥ {KEEP_FRACTION:.0%} of the seeds at "
                f"every {quantity} {listed}"
            )
            same = _alike([(s, self.success[(c, s)]) for s in self.strategies])
            if same:
                text += "; " + "; ".join(
                    f"{' and '.join(g)} keep the same share at every point" for g in same
                )
            out.append(text + ".")
        return out


def _alike(rows: Sequence[tuple[str, Array]]) -> list[list[str]]:
    """Names whose arrays are equal, in groups of two or more."""
    groups: list[list[tuple[str, Array]]] = []
    for name, v in rows:
        for g in groups:
            if np.array_equal(g[0][1], v):
                g.append((name, v))
                break
        else:
            groups.append([(name, v)])
    return [[f"`{n}`" for n, _ in g] for g in groups if len(g) > 1]


def _times(value: float | None) -> str:
    return "none" if value is None else f"{value:g} ×"


def write_outputs(
    r: GridResult,
    out: Path,
    fields: Sequence[str],
    critical_title: str,
    results: str,
    threshold_m: float,
    **plot: Any,
) -> None:
    """``runs.csv`` (``fields`` of every cell), ``critical.md``, ``results.md`` and
    ``phase.png`` (:func:`plot_range_phase` with ``plot``'s options) in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    write_cells(out / "runs.csv", r.rows, fields)
    (out / "critical.md").write_text(f"# {critical_title}\n\n" + r.critical_markdown())
    (out / "results.md").write_text(results)
    plot_range_phase(
        r.success,
        r.critical,
        r.points,
        r.columns,
        r.strategies,
        threshold_m,
        out / "phase.png",
        **plot,
    )


def write_cells(path: Path, rows: Iterable[dict[str, Any]], fields: Sequence[str]) -> None:
    """The rows' ``fields`` as CSV, finite floats in full (``repr``)."""
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=fields)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: _cell(row[k]) for k in fields})


def _cell(v: Any) -> Any:
    return repr(v) if isinstance(v, float) and math.isfinite(v) else v


__all__ = [
    "KEEP_FRACTION",
    "GridResult",
    "Judge",
    "PlanMeasure",
    "Variant",
    "critical",
    "kept_fraction",
    "over_grid",
    "progress",
    "run_grid",
    "write_cells",
    "write_outputs",
]
