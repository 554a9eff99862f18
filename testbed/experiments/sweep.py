"""``formation sweep``: the critical loss rate of each strategy, per topology and loss model.

The question the chapter leaves open (docs/model.md §8): the largest loss rate at which a strategy still
keeps the formation. A **cell** is one topology × loss model × loss rate × strategy × seed run of
``epochs`` epochs with every formation link under the same loss (the scenario's own formation
network is replaced; its control links are kept). A loss model named ``tag.param`` instead keeps
the scenario's network and sets ``param`` of its link models ``tag`` to each value of the grid
(``formation sweep --vary jammer.length=0:30:5``; ``loss_variants.with_parameter``). A cell **keeps the formation** when its final
shape error (docs/model.md §7; the team's at the last epoch with an agent in it, as a run's
summary takes it: :func:`analysis.final_value`) is under ``threshold_m``; a loss rate is kept when
≥ 95 % of the seeds keep it; the **critical loss rate** is the largest grid rate up to which every
rate is kept (:func:`testbed.experiments.grid.critical`).

Loss models at equal mean rate ``ρ``: Bernoulli ``p_loss = ρ``; Gilbert–Elliott with loss only in
the bad state and mean burst ``β`` epochs (``r = 1/β``, ``p = ρ r / (1 − ρ)``; when that ``p``
exceeds 1, ``p = 1`` and ``r = (1 − ρ)/ρ``, longer bursts), so ``π_bad = ρ``
(``netem.links.models.expected_loss_rate`` checks it).

The cells are a grid (:func:`testbed.experiments.grid.run_grid`), run in chunks of one
topology × model × seed group (every loss rate and strategy: the noise is drawn once per seed,
the schedules once per rate and seed) and the
chunks go to an executor (``testbed.experiments.executors``: the local process pool, or a Dask
cluster), with enough seeds per chunk that a task's overhead stays under 5 % of it. Every finished
chunk is appended to ``runs.csv`` as it comes; a re-run, on any executor, skips the cells already
there, and the final CSV and tables are written in a canonical order, so the same sweep gives
byte-identical files however and wherever it ran or was interrupted.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from analysis import final_value
from formation.errors import SweepError
from formation.markdown import table
from formation.plugin_api import all_strategies
from formation.scenario import Scenario, StrategyName
from testbed.experiments.executors import Executor, LocalPool, seeds_per_task
from testbed.experiments.grid import (
    KEEP_FRACTION,
    GridResult,
    Variant,
    critical,
    over_grid,
    run_grid,
)
from testbed.experiments.loss_variants import LOSS_MODELS, is_parameter, with_loss
from testbed.experiments.plots import plot_phase
from testbed.experiments.sweep_spec import Key, SweepSpec, loss_grid, loss_label, value_grid
from testbed.sim.batch import BatchResult
from testbed.sim.plan import BatchPlan

COLUMNS = (
    "topology",
    "model",
    "loss",
    "strategy",
    "seed",
    "epochs",
    "final_shape_error_m",
    "final_formation_error_m",
    "measured_loss",
)


@dataclass(frozen=True)
class Chunk:
    """One unit of work: a topology × model × seed group, every loss rate and strategy."""

    topology: str
    scenario: Scenario
    model: str
    losses: tuple[float, ...]
    seeds: tuple[int, ...]
    strategies: tuple[StrategyName, ...]
    epochs: int
    burst_epochs: float
    done: frozenset[Key] = field(default_factory=frozenset)

    @property
    def cells(self) -> int:
        return len(self.losses) * len(self.seeds) * len(self.strategies) - len(self.done)


def run_chunk(chunk: Chunk) -> list[dict[str, Any]]:
    """Simulate the cells of ``chunk`` not in ``chunk.done``; one CSV row per cell."""
    variants = [
        Variant(
            {"topology": chunk.topology, "model": chunk.model, "loss": loss_label(p)},
            with_loss(chunk.scenario, chunk.model, p, chunk.burst_epochs),
        )
        for p in chunk.losses
    ]

    def done(v: Variant, strategy: StrategyName, seed: int) -> bool:
        k = v.keys
        return (k["topology"], k["model"], k["loss"], strategy, seed, chunk.epochs) in chunk.done

    frame = run_grid(
        variants,
        chunk.seeds,
        chunk.strategies,
        final_errors,
        planned=measured_loss,
        epochs=chunk.epochs,
        skip=done,
    )
    frame["epochs"] = chunk.epochs
    return [
        {c: _num(cell[c]) if c in MEASURED else cell[c] for c in COLUMNS}
        for cell in frame.to_dict("records")
    ]


MEASURED = ("final_shape_error_m", "final_formation_error_m", "measured_loss")


def final_errors(res: BatchResult) -> dict[str, np.ndarray]:
    """(B,) the final shape and formation error of each member [m]: the team's at the last
    epoch with an agent in it, as a run's summary takes them (:func:`analysis.final_value`)."""
    formation, shape = res.team_errors()
    team = res.plan.team
    everyone = np.ones((len(shape), res.plan.base.n), dtype=bool)
    present = everyone if team is None else team.published

    def final(values: np.ndarray) -> np.ndarray:
        out = [final_value(values[:, b], present) for b in range(values.shape[1])]
        return np.array([math.nan if v is None else v for v in out])

    return {"final_shape_error_m": final(shape), "final_formation_error_m": final(formation)}


def measured_loss(plan: BatchPlan) -> dict[str, np.ndarray]:
    """(B,) the share of formation packets the plan does not deliver in time."""
    return {"measured_loss": 1.0 - plan.on_time.mean(axis=(0, 2))}


def _num(v: float) -> str:
    v = float(v)
    return format(v, ".9g") if math.isfinite(v) else ("nan" if math.isnan(v) else "inf")


def _key(row: dict[str, Any]) -> Key:
    return (
        str(row["topology"]),
        str(row["model"]),
        str(row["loss"]),
        str(row["strategy"]),
        int(row["seed"]),
        int(row["epochs"]),
    )


def read_rows(path: Path) -> list[dict[str, str]]:
    """The rows of an existing ``runs.csv`` (none if it does not exist)."""
    if not path.exists():
        return []
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        if tuple(reader.fieldnames or ()) != COLUMNS:
            raise SweepError(
                str(path),
                f"columns {reader.fieldnames}; expected {list(COLUMNS)} "
                "(move the file away to start afresh)",
            )
        return [row for row in reader if _complete(row)]


def _complete(row: dict[str, Any]) -> bool:
    """A whole row (an interrupted write can leave the last one cut short)."""
    if None in row or any(row.get(c) in (None, "") for c in COLUMNS):
        return False
    try:
        _key(row)
        float(row["final_shape_error_m"])
    except ValueError:
        return False
    return True


def plan_chunks(spec: SweepSpec, done: set[Key]) -> list[Chunk]:
    """The chunks that still have cells to run, heaviest first (balances the pool)."""
    chunks: list[Chunk] = []
    step = max(1, spec.seeds_per_chunk)
    for name, scenario in spec.topologies:
        for model in spec.models:
            for start in range(0, len(spec.seeds), step):
                seeds = spec.seeds[start : start + step]
                keys = {
                    (name, model, loss_label(p), s, seed, spec.epochs)
                    for p in spec.losses
                    for s in spec.strategies
                    for seed in seeds
                }
                have = frozenset(keys & done)
                if len(have) < len(keys):
                    chunks.append(
                        Chunk(
                            name,
                            scenario,
                            model,
                            spec.losses,
                            seeds,
                            spec.strategies,
                            spec.epochs,
                            spec.burst_epochs,
                            have,
                        )
                    )
    return sorted(chunks, key=lambda c: -c.cells * (c.scenario.n + len(c.scenario.directed_links)))


def run_sweep(
    spec: SweepSpec,
    out_dir: Path,
    jobs: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    executor: Executor | None = None,
) -> SweepSummary:
    """Run the sweep into ``out_dir/runs.csv`` (resuming it) and write the tables.

    ``executor`` runs the chunks (default: the local pool of ``jobs`` worker processes, every
    core by default; 1 runs in this process). ``progress(done, total)`` is called as cells finish.
    """
    executor = executor or LocalPool(jobs)
    per_seed = len(spec.losses) * len(spec.strategies)
    seeds = seeds_per_task(spec.seeds_per_chunk, per_seed, spec.epochs, executor.task_overhead_s)
    spec = replace(spec, seeds_per_chunk=seeds)  # the rows do not depend on the chunking
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "runs.csv"
    rows = read_rows(path)
    done = {_key(r) for r in rows}
    wanted = spec.keys()
    total = len(wanted)
    finished = sum(1 for k in wanted if k in done)
    chunks = plan_chunks(spec, done)
    if progress is not None:
        progress(finished, total)
    if chunks:
        new_file = not path.exists()
        if not new_file and not path.read_bytes().endswith(b"\n"):
            with path.open("a") as f:
                f.write("\n")  # end a row cut short, so the next one starts on its own line
        with path.open("a", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=COLUMNS, lineterminator="\n")
            if new_file:
                writer.writeheader()
                f.flush()
            for got in executor.map_unordered(run_chunk, chunks):
                writer.writerows(got)
                f.flush()
                rows.extend({k: str(v) for k, v in r.items()} for r in got)
                finished += len(got)
                if progress is not None:
                    progress(finished, total)
    _write_canonical(path, rows, spec)
    summary = sweep_summary(rows, spec)
    write_tables(summary, out_dir)
    return summary


def _write_canonical(path: Path, rows: list[dict[str, Any]], spec: SweepSpec) -> None:
    """Rewrite the CSV sorted, one row per cell, so identical sweeps give identical bytes."""
    topo = {name: i for i, (name, _) in enumerate(spec.topologies)}
    strat: dict[str, int] = {str(s): i for i, s in enumerate(all_strategies())}
    model = {m: i for i, m in enumerate(LOSS_MODELS)}
    unique: dict[Key, dict[str, Any]] = {}
    for r in rows:
        unique.setdefault(_key(r), r)

    def order(k: Key) -> tuple[Any, ...]:
        return (
            topo.get(k[0], len(topo)),
            k[0],
            model.get(k[1], 9),
            float(k[2]),
            strat.get(k[3], 9),
            k[4],
            k[5],
        )

    tmp = path.with_suffix(".csv.tmp")
    with tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS, lineterminator="\n")
        writer.writeheader()
        for k in sorted(unique, key=order):
            writer.writerow({c: unique[k][c] for c in COLUMNS})
    tmp.replace(path)


@dataclass(frozen=True)
class SweepSummary:
    """Success fractions and critical loss rates of a sweep.

    success : (topology, model, strategy) → (L,) fraction of seeds that kept the formation
    critical : (topology, model, strategy) → the critical loss rate, None if even 0 fails
    """

    spec: SweepSpec
    success: dict[tuple[str, str, str], np.ndarray]
    median_error: dict[tuple[str, str, str], np.ndarray]
    measured_loss: dict[tuple[str, str], np.ndarray]
    critical: dict[tuple[str, str, str], float | None]


def sweep_summary(rows: Iterable[dict[str, Any]], spec: SweepSpec) -> SweepSummary:
    """Per topology, model and strategy: success fraction per loss rate, and the critical rate."""
    cells = _spec_cells(rows, spec)
    cells["kept"] = cells["final_shape_error_m"] < spec.threshold_m
    by, grid = ("topology", "model", "strategy"), [loss_label(p) for p in spec.losses]
    success = over_grid(cells, by, "loss", grid, lambda c: float(np.mean(c["kept"].to_numpy())))
    median = over_grid(
        cells, by, "loss", grid, lambda c: float(np.median(c["final_shape_error_m"].to_numpy()))
    )
    first = cells[cells["strategy"] == spec.strategies[0]]
    measured = over_grid(
        first,
        ("topology", "model"),
        "loss",
        grid,
        lambda c: float(np.mean(c["measured_loss"].to_numpy())),
    )
    keys = [(t, m, s) for t, _ in spec.topologies for m in spec.models for s in spec.strategies]
    nan = np.full(len(grid), math.nan)
    success = {k: success.get(k, nan) for k in keys}
    return SweepSummary(
        spec,
        success,
        {k: median.get(k, nan) for k in keys},
        {(t, m): measured.get((t, m), nan) for t, m, _ in keys},
        {k: critical(spec.losses, v, easiest="low") for k, v in success.items()},
    )


def _spec_cells(rows: Iterable[dict[str, Any]], spec: SweepSpec) -> pd.DataFrame:
    """The rows of ``spec``'s cells (the last of each) in the CSV's order, numbers parsed."""
    index = {_key(r): r for r in rows}
    names = ("topology", "model", "loss", "strategy", "seed")
    wanted = [k for k in spec.keys() if k in index]  # noqa: SIM118 (a spec's, not a dict's)
    return pd.DataFrame(
        [
            {**dict(zip(names, k[:5], strict=True)), **{c: float(index[k][c]) for c in MEASURED}}
            for k in wanted
        ],
        columns=[*names, *MEASURED],
    )


def critical_table(summary: SweepSummary) -> str:
    """Markdown: the critical loss rate per topology and model (rows) and strategy (columns)."""
    spec = summary.spec
    rows = (
        [name, m]
        + [
            "none" if (c := summary.critical[(name, m, s)]) is None else loss_label(c)
            for s in spec.strategies
        ]
        for name, _ in spec.topologies
        for m in spec.models
    )
    return table(["topology", "loss model", *spec.strategies], rows)


def success_table(summary: SweepSummary) -> str:
    """Markdown: success fraction per loss rate, one table per topology and model."""
    spec = summary.spec
    out: list[str] = []
    for name, _ in spec.topologies:
        for m in spec.models:
            meas = summary.measured_loss[(name, m)]
            rows = (
                [loss_label(p), f"{meas[i]:.3f}"]
                + [f"{summary.success[(name, m, s)][i]:.2f}" for s in spec.strategies]
                for i, p in enumerate(spec.losses)
            )
            out.append(f"\n### {name}, {m}\n")
            out.append(table(["loss", "measured", *spec.strategies], rows).rstrip("\n"))
    return "\n".join(out) + "\n"


def _variants_said(spec: SweepSpec) -> str:
    """What the rows' loss models are, for the tables' heading."""
    if all(is_parameter(m) for m in spec.models):
        return (
            "the scenario's own link models, the parameter named in the loss-model column "
            "set to each value of the 'loss' column"
        )
    return (
        "every formation link under the same loss; Gilbert–Elliott at equal mean rate with "
        f"mean burst {spec.burst_epochs:g} epochs"
    )


def conclusion(summary: SweepSummary) -> str:
    """A sentence per topology and loss model: up to which rate each strategy keeps the
    formation, the most tolerant first, and which strategies keep the same share at every
    rate (:meth:`testbed.experiments.grid.GridResult.conclusion`)."""
    spec = summary.spec

    def by_column(values: dict[tuple[str, str, str], Any]) -> dict[tuple[str, str], Any]:
        return {(f"{t}, {m}", s): v for (t, m, s), v in values.items()}

    grid = GridResult(
        frame=pd.DataFrame(),
        strategies=spec.strategies,
        points=spec.losses,
        columns=tuple(f"{t}, {m}" for t, _ in spec.topologies for m in spec.models),
        success=by_column(summary.success),
        critical=by_column(summary.critical),
    )
    varied = all(is_parameter(m) for m in spec.models)
    quantity = "value of the varied parameter" if varied else "loss rate"
    return " ".join(grid.conclusion(quantity, "low", written=loss_label))


def write_tables(summary: SweepSummary, out_dir: Path) -> None:
    """``critical.md`` (the answer), ``success.md`` (the fractions) and ``phase.png``, each
    table opening with :func:`conclusion`."""
    spec = summary.spec
    topo = ", ".join(f"{n} (n = {s.n}, d = {s.dimension})" for n, s in spec.topologies)
    said = conclusion(summary)
    text = (
        f"# Critical loss rate per strategy\n\n{said}\n\n"
        f"Largest loss rate up to which the final shape error after {spec.epochs} epochs is under "
        f"{spec.threshold_m:g} m in ≥ {KEEP_FRACTION:.0%} of {len(spec.seeds)} seeds "
        f"(seeds {spec.seeds[0]}–{spec.seeds[-1]}); {_variants_said(spec)}.\n"
        f"Topologies: {topo}.\n\n" + critical_table(summary)
    )
    (out_dir / "critical.md").write_text(text)
    (out_dir / "success.md").write_text(
        f"# Fraction of seeds keeping the formation\n\n{said}\n" + success_table(summary)
    )
    names = [n for n, _ in spec.topologies]
    grid = (names, spec.models, spec.strategies)
    plot_phase(
        summary.success,
        summary.critical,
        spec.losses,
        grid,
        spec.threshold_m,
        out_dir / "phase.png",
    )


__all__ = [
    "COLUMNS",
    "Chunk",
    "SweepSpec",
    "SweepSummary",
    "conclusion",
    "critical_table",
    "loss_grid",
    "loss_label",
    "read_rows",
    "run_chunk",
    "run_sweep",
    "success_table",
    "sweep_summary",
    "value_grid",
    "write_tables",
]
