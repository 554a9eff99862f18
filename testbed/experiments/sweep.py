"""``formation sweep``: the critical loss rate of each strategy, per topology and loss model.

The question the chapter leaves open (docs/model.md §8): the largest loss rate at which a strategy still
keeps the formation. A **cell** is one topology × loss model × loss rate × strategy × seed run of
``epochs`` epochs with every formation link under the same loss (the scenario's own formation
network is replaced; its control links are kept). A cell **keeps the formation** when its final
shape error (docs/model.md §7; with scenario events, over the edges between the agents taking part
at the end, ``BatchResult.team_errors``) is under ``threshold_m``; a loss rate is kept when ≥ 95 % of the seeds
keep it; the **critical loss rate** is the largest grid rate up to which every rate is kept.

Loss models at equal mean rate ``ρ``: Bernoulli ``p_loss = ρ``; Gilbert–Elliott with loss only in
the bad state and mean burst ``β`` epochs (``r = 1/β``, ``p = ρ r / (1 − ρ)``; when that ``p``
exceeds 1, ``p = 1`` and ``r = (1 − ρ)/ρ``, longer bursts), so ``π_bad = ρ``
(``netem.links.models.expected_loss_rate`` checks it).

Runs are batched (``testbed.sim.batch``) in chunks of one topology × model × seed group (every loss
rate and strategy: the noise is drawn once per seed, the schedules once per rate and seed) and the
chunks go to an executor (``testbed.experiments.executors``: the local process pool, or a Dask
cluster), with enough seeds per chunk that a task's overhead stays under 5 % of it. Every finished
chunk is appended to ``runs.csv`` as it comes; a re-run, on any executor, skips the cells already
there, and the final CSV and tables are written in a canonical order, so the same sweep gives
byte-identical files however and wherever it ran or was interrupted.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from formation.errors import SweepError
from formation.plugin_api import all_strategies
from formation.scenario import Scenario, StrategyName
from testbed.experiments.executors import Executor, LocalPool, seeds_per_task
from testbed.experiments.loss_variants import LOSS_MODELS, with_loss
from testbed.experiments.plots import plot_phase
from testbed.experiments.studies import KEEP_FRACTION
from testbed.sim.batch import plan_batch, run_batch

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
Key = tuple[str, str, str, str, int, int]  # topology, model, loss, strategy, seed, epochs


def loss_grid(text: str) -> tuple[float, ...]:
    """``"0:1:0.05"`` → 0, 0.05, …, 1 (both ends); ``"0.1,0.3"`` → those rates."""
    try:
        if ":" in text:
            start, stop, step = (float(v) for v in text.split(":"))
            if step <= 0:
                raise SweepError(f"--loss {text!r}: step = {step:g}; expected > 0")
            count = math.floor((stop - start) / step + 1e-9) + 1
            values = [round(start + i * step, 10) for i in range(count)]
        else:
            values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise SweepError(
            f"--loss {text!r}: expected START:STOP:STEP or a comma list of rates"
        ) from None
    bad = [v for v in values if not 0.0 <= v <= 1.0]
    if not values or bad:
        raise SweepError(f"--loss {text!r}: rates must be in [0, 1], got {bad or 'none'}")
    return tuple(sorted(set(values)))


def loss_label(rate: float) -> str:
    """The loss rate as written in the CSV and the tables (e.g. ``0.05``)."""
    return f"{rate:.6g}"


@dataclass(frozen=True)
class SweepSpec:
    """What a sweep covers; every cell is ``(topology, model, loss, strategy, seed)``."""

    topologies: tuple[tuple[str, Scenario], ...]
    losses: tuple[float, ...]
    strategies: tuple[StrategyName, ...]
    seeds: tuple[int, ...]
    models: tuple[str, ...] = ("bernoulli",)
    epochs: int = 200
    threshold_m: float = 0.05
    burst_epochs: float = 4.0
    seeds_per_chunk: int = 10

    def keys(self) -> list[Key]:
        """Every cell, in the canonical order of the CSV."""
        return [
            (t, m, loss_label(p), s, seed, self.epochs)
            for t, _ in self.topologies
            for m in self.models
            for p in self.losses
            for s in self.strategies
            for seed in self.seeds
        ]


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
    variants = {
        p: with_loss(chunk.scenario, chunk.model, p, chunk.burst_epochs) for p in chunk.losses
    }
    members = [(p, seed) for p in chunk.losses for seed in chunk.seeds]
    plan = plan_batch([variants[p] for p, _ in members], [s for _, s in members], chunk.epochs)
    measured = 1.0 - plan.on_time.mean(axis=(0, 2))
    rows: list[dict[str, Any]] = []
    for strategy in chunk.strategies:
        keys = [
            (chunk.topology, chunk.model, loss_label(p), strategy, seed, chunk.epochs)
            for p, seed in members
        ]
        todo = [b for b, key in enumerate(keys) if key not in chunk.done]
        if not todo:
            continue
        sub = plan if len(todo) == len(members) else plan.subset(todo)
        with np.errstate(all="ignore"):  # a diverging run is a lost formation, not an error
            res = run_batch(sub, strategy, detail=False)
            formation, shape = res.team_errors()  # with events: the team taking part at the end
        for i, b in enumerate(todo):
            t, m, p, s, seed, e = keys[b]
            rows.append(
                {
                    "topology": t,
                    "model": m,
                    "loss": p,
                    "strategy": s,
                    "seed": seed,
                    "epochs": e,
                    "final_shape_error_m": _num(shape[-1, i]),
                    "final_formation_error_m": _num(formation[-1, i]),
                    "measured_loss": _num(measured[b]),
                }
            )
    return rows


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
                f"{path}: columns {reader.fieldnames}; expected {list(COLUMNS)} (move the file away to start afresh)"
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
    summary = summarise(rows, spec)
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


def critical_rate(
    losses: Sequence[float], success: np.ndarray, keep: float = KEEP_FRACTION
) -> float | None:
    """Largest grid rate such that every rate up to it is kept (success ≥ ``keep``)."""
    best = None
    for p, frac in zip(losses, success, strict=True):
        if not frac >= keep:
            break
        best = p
    return best


def summarise(rows: Iterable[dict[str, Any]], spec: SweepSpec) -> SweepSummary:
    """Per topology, model and strategy: success fraction per loss rate, and the critical rate."""
    index = {_key(r): r for r in rows}
    success: dict[tuple[str, str, str], np.ndarray] = {}
    median: dict[tuple[str, str, str], np.ndarray] = {}
    measured: dict[tuple[str, str], np.ndarray] = {}
    critical: dict[tuple[str, str, str], float | None] = {}
    for name, _ in spec.topologies:
        for m in spec.models:
            meas = []
            for p in spec.losses:
                vals = [
                    float(index[k]["measured_loss"])
                    for seed in spec.seeds
                    if (k := (name, m, loss_label(p), spec.strategies[0], seed, spec.epochs))
                    in index
                ]
                meas.append(float(np.mean(vals)) if vals else math.nan)
            measured[(name, m)] = np.array(meas)
            for s in spec.strategies:
                frac, med = [], []
                for p in spec.losses:
                    errs = np.array(
                        [
                            float(index[k]["final_shape_error_m"])
                            for seed in spec.seeds
                            if (k := (name, m, loss_label(p), s, seed, spec.epochs)) in index
                        ]
                    )
                    frac.append(float(np.mean(errs < spec.threshold_m)) if errs.size else math.nan)
                    med.append(float(np.median(errs)) if errs.size else math.nan)
                success[(name, m, s)] = np.array(frac)
                median[(name, m, s)] = np.array(med)
                critical[(name, m, s)] = critical_rate(spec.losses, success[(name, m, s)])
    return SweepSummary(spec, success, median, measured, critical)


def critical_table(summary: SweepSummary) -> str:
    """Markdown: the critical loss rate per topology and model (rows) and strategy (columns)."""
    spec = summary.spec
    head = "| topology | loss model | " + " | ".join(spec.strategies) + " |"
    lines = [head, "|" + " --- |" * (2 + len(spec.strategies))]
    for name, _ in spec.topologies:
        for m in spec.models:
            cells = []
            for s in spec.strategies:
                c = summary.critical[(name, m, s)]
                cells.append("none" if c is None else loss_label(c))
            lines.append(f"| {name} | {m} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def success_table(summary: SweepSummary) -> str:
    """Markdown: success fraction per loss rate, one table per topology and model."""
    spec = summary.spec
    out: list[str] = []
    for name, _ in spec.topologies:
        for m in spec.models:
            out.append(f"\n### {name}, {m}\n")
            out.append("| loss | measured | " + " | ".join(spec.strategies) + " |")
            out.append("|" + " --- |" * (2 + len(spec.strategies)))
            meas = summary.measured_loss[(name, m)]
            for i, p in enumerate(spec.losses):
                fr = [f"{summary.success[(name, m, s)][i]:.2f}" for s in spec.strategies]
                out.append(f"| {loss_label(p)} | {meas[i]:.3f} | " + " | ".join(fr) + " |")
    return "\n".join(out) + "\n"


def write_tables(summary: SweepSummary, out_dir: Path) -> None:
    """``critical.md`` (the answer), ``success.md`` (the fractions) and ``phase.png``."""
    spec = summary.spec
    topo = ", ".join(f"{n} (n = {s.n}, d = {s.dimension})" for n, s in spec.topologies)
    text = (
        "# Critical loss rate per strategy\n\n"
        f"Largest loss rate up to which the final shape error after {spec.epochs} epochs is under "
        f"{spec.threshold_m:g} m in ≥ {KEEP_FRACTION:.0%} of {len(spec.seeds)} seeds "
        f"(seeds {spec.seeds[0]}–{spec.seeds[-1]}); every formation link under the same loss; "
        f"Gilbert–Elliott at equal mean rate with mean burst {spec.burst_epochs:g} epochs.\n"
        f"Topologies: {topo}.\n\n" + critical_table(summary)
    )
    (out_dir / "critical.md").write_text(text)
    (out_dir / "success.md").write_text(
        "# Fraction of seeds keeping the formation\n" + success_table(summary)
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
    "critical_rate",
    "critical_table",
    "loss_grid",
    "loss_label",
    "read_rows",
    "run_chunk",
    "run_sweep",
    "summarise",
    "write_tables",
]
