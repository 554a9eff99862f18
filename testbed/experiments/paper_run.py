"""``formation experiment paper``, the whole run: the study, its figures, its real-process runs and its files.

The study itself (variants, claims) is :mod:`testbed.experiments.paper`; the text of
``results.md`` and ``seeds.csv`` is :mod:`testbed.experiments.report`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from analysis import error_statistics
from formation.markdown import table
from formation.reference import reference_positions
from formation.scenario import STRATEGIES, Scenario, StrategyName
from recorder import KEEP_M, read_run
from testbed.experiments import plots, studies
from testbed.experiments.findings import identical_notes, noise_floor
from testbed.experiments.loss_variants import with_loss
from testbed.experiments.paper import (
    PLOTTED_AGENTS,
    Array,
    PaperResults,
    final_errors,
    judge,
    run_variants,
)
from testbed.experiments.report import results_markdown, seeds_csv
from testbed.runtime.launcher import launch
from testbed.sim.batch import BatchResult
from testbed.sim.simulate import simulate
from testbed.sim.team_generators import henneberg_team

# ------------------------------------------------------------------------------ figures


def _desired(res: BatchResult) -> Array:
    base = res.plan.base
    d0, r = base.offsets, base.reference_agent
    ref = reference_positions(base.reference, d0[r - 1], base.control.period_s, res.plan.epochs)
    return np.asarray(ref[:, None, :] + (d0 - d0[r - 1])[None, :, :])


FIGURES = {
    "failure": "formation_error_failure.png",
    "one lossy link": "formation_error_one_lossy.png",
    "two lossy links": "formation_error_two_lossy.png",
    "failure, 500 epochs": "formation_error_500.png",
}
"""The formation error figure of each variant."""


def write_figures(r: PaperResults, out: Path) -> None:
    fail = r.runs["failure"]
    notes = identical_notes(fail)
    desired = _desired(fail["estimate"])
    b = 0  # the scenario's seed (first of the list) for the position figures
    pos = {s: res.positions[:, b] for s, res in fail.items()}
    title = f"{r.scenario.name}: link 1–2 down from epoch 1, seed {r.seeds[b]}"
    plots.plot_agent_positions(pos, desired, PLOTTED_AGENTS, out / "positions.png", title, notes)
    plots.plot_strategy_paths(pos, desired, PLOTTED_AGENTS, out / "trajectories.png", title, notes)
    traces = {}
    for s, res in fail.items():
        if s == "drop":
            continue
        t = np.full(res.plan.epochs, np.nan)
        for k in range(res.plan.epochs):
            t[k] = error_statistics(res.sub_error[res.sub_epoch == k])[2]
        traces[s] = t
    plots.plot_covariance_over_epochs(
        traces,
        out / "substitution_covariance.png",
        f"substitution error covariance over {len(r.seeds)} seeds, link 1–2 down",
        identical_notes({s: fail[s] for s in traces}, "sub_error"),
    )
    for variant, fname in FIGURES.items():
        runs = r.runs[variant]
        series = {s: res.formation_error for s, res in runs.items()}
        plots.plot_error_bands(
            series,
            out / fname,
            f"{variant}: formation error, median and 10–90 % of {len(r.seeds)} seeds",
            "formation error [m]",
            notes=identical_notes(runs),
            keep_m=KEEP_M,
            floor_m=noise_floor(runs),
        )
    if "alpha" in r.studies:
        a = r.studies["alpha"]
        plots.plot_alpha_curve(
            a.curves[0].alphas,
            {c.label: c.relative for c in a.curves},
            {c.label: c.best for c in a.curves},
            out / "alpha.png",
            "blend: error against α",
        )
    if "dynamic" in r.studies:
        d = r.studies["dynamic"]
        plots.plot_dynamic(
            d.shape_error,
            d.tree_edges,
            d.leave[1],
            d.join[1],
            out / "dynamic.png",
            f"agent {d.leave[0]} leaves at {d.leave[1]}, agent {d.join[0]} joins at {d.join[1]}",
            notes={
                s: "same shape error as estimate in every seed"
                for s in d.shape_error
                if s != "estimate"
                and np.array_equal(d.shape_error[s], d.shape_error.get("estimate"), equal_nan=True)
            },
        )


# ------------------------------------------------------------------------------ real processes


def representative_seed(res: BatchResult) -> int:
    """The seed whose final formation error is closest to the median (lowest seed on ties)."""
    v = final_errors(res)
    gap = np.abs(v - np.median(v))
    return int(res.plan.seeds[int(np.argmin(gap))])


def run_real(
    r: PaperResults,
    out: Path,
    record: bool = True,
    log: Callable[[str], None] = print,
    strategies: Sequence[StrategyName] = STRATEGIES,
) -> None:
    """Each strategy's representative seed through real processes; compares positions."""
    runs_dir = out / "runs"
    rows: list[list[object]] = []
    for s in strategies:
        res = r.runs["failure"][s]
        seed = representative_seed(res)
        b = int(np.flatnonzero(res.plan.seeds == seed)[0])
        sim_x = res.positions[:, b]
        row: dict[str, Any] = {
            "strategy": s,
            "seed": seed,
            "sim_final": float(res.formation_error[-1, b]),
        }
        log(f"real processes: {s}, seed {seed} …")
        try:
            outcome = launch(
                r.scenario, strategy=res.strategy, seed=seed, runs_dir=runs_dir, record=record
            )
        except Exception as exc:  # a failed launch is reported, not fatal to the experiment
            row["max_diff_text"] = f"launch failed: {type(exc).__name__}"
            rows.append([s, seed, "-", "-", f"launch failed: {exc}", "-"])
            r.real.append(row)
            continue
        diff = float(np.max(np.abs(outcome.positions - sim_x)))
        row["real_final"] = float(outcome.formation_error[-1])
        row["max_diff_text"] = f"{diff:.1e}"
        ok = diff <= 1e-9
        rec_note, skipped = "not recorded (--no-record)", "-"
        if record:
            rec_note, skipped = check_recording(row, outcome.run_dir / "run.mcap", sim_x)
            ok = ok and row.get("recorded_diff", np.inf) <= 1e-9
        row["match"] = "yes" if ok else "no"
        rows.append([s, seed, f"`{outcome.run_id}`", f"{outcome.wall_s:.1f}", rec_note, skipped])
        r.real.append(row)
    rows.append(run_events_real(r, runs_dir, record, log))
    header = ["strategy", "seed", "run id", "wall [s]", "recording", "skipped"]
    text = "# Real-process runs of `formation experiment paper`\n\n" + table(header, rows)
    (out / "real_runs.md").write_text(text + "\n" + SKIPPED_NOTE + "\n")


SKIPPED_NOTE = (
    "skipped: recorded messages the reader did not trust and left out (not valid against their "
    "model, a sender that is not the key's owner, an epoch or agent outside the scenario; "
    "`recorder.reading.trust`), by reason; each run's `report.md` has them per channel."
)


def check_recording(
    row: dict[str, Any], mcap: Path, sim_x: Array, published: npt.NDArray[np.bool_] | None = None
) -> tuple[str, str]:
    """Read a real run's recording back: its positions against the simulation's
    (``row["recorded_diff"]``, NaN if one is missing; ``published``: (E + 1, n, d) the states
    the agents published, default all) and what the reader skipped (``row["skipped"]``);
    returns the table's recording and skipped cells."""
    try:
        rec = read_run(mcap)
    except Exception as exc:  # the recording is checked, its reader is another module
        row["recorded_diff_text"] = f"unreadable: {type(exc).__name__}"
        return f"{mcap} (read failed: {exc})", "-"
    on = np.ones(sim_x.shape, dtype=bool) if published is None else published
    row["recorded_diff"] = rdiff = float(np.max(np.abs(rec.positions[on] - sim_x[on])))
    row["recorded_diff_text"] = f"{rdiff:.1e}" + (
        "" if published is None else " (published states)"
    )
    assert rec.recorded is not None  # a record read from a recording has its section
    skipped = rec.recorded.skipped
    row["skipped"] = skipped.total
    reasons = ", ".join(f"{k} {v}" for k, v in skipped.by_reason().items())
    return str(mcap), f"{skipped.total}" + (f" ({reasons})" if reasons else "")


def run_events_real(
    r: PaperResults, runs_dir: Path, record: bool, log: Callable[[str], None]
) -> list[object]:
    """The dynamic-formation study's team with its leave and join as scenario events, through
    real processes, against ``simulate`` where states were published; returns its table row."""
    scenario = studies.dynamic_team(r.scenario, leave=(5, 20), join=(6, 35))
    label = "estimate (events: 5 leaves at 20, 6 joins at 35)"
    sim = simulate(scenario, strategy="estimate")
    row: dict[str, Any] = {
        "strategy": label,
        "seed": scenario.seed,
        "sim_final": float(sim.formation_error[-1]),
    }
    log(f"real processes: {label} …")
    try:
        outcome = launch(scenario, strategy="estimate", runs_dir=runs_dir, record=record)
    except Exception as exc:  # a failed launch is reported, not fatal to the experiment
        row["max_diff_text"] = f"launch failed: {type(exc).__name__}"
        r.real.append(row)
        return [label, scenario.seed, "-", "-", f"launch failed: {exc}", "-"]
    seen = np.isfinite(outcome.positions)
    diff = float(np.max(np.abs(outcome.positions[seen] - sim.positions[seen])))
    row["real_final"] = float(outcome.formation_error[-1])  # bodies out of the team held
    row["max_diff_text"] = f"{diff:.1e} (published states)"
    ok = diff <= 1e-9
    where, skipped = "not recorded (--no-record)", "-"
    if record:
        where, skipped = check_recording(row, outcome.run_dir / "run.mcap", sim.positions, seen)
        ok = ok and row.get("recorded_diff", np.inf) <= 1e-9
    row["match"] = "yes" if ok else "no"
    r.real.append(row)
    return [label, scenario.seed, f"`{outcome.run_id}`", f"{outcome.wall_s:.1f}", where, skipped]


# ------------------------------------------------------------------------------ the whole experiment


def run_paper(
    scenario: Scenario,
    out: Path,
    seeds: Sequence[int] = tuple(range(1, 21)),
    real: bool = True,
    record: bool = True,
    extras: bool = True,
    log: Callable[[str], None] = print,
    figures: bool = True,
) -> PaperResults:
    """Run the paper experiment and write ``out``; returns everything measured.

    ``extras``: the studies beyond the chapter (§7.2 controllers, estimator, α, dynamic);
    ``real``/``record``: the real-process runs and their recording; ``figures``: the PNGs.
    """
    out.mkdir(parents=True, exist_ok=True)
    seeds = tuple(int(s) for s in seeds)
    r = PaperResults(scenario, seeds, {})
    t0 = time.perf_counter()
    log(f"the chapter's variants, {len(seeds)} seeds ...")
    r.runs = run_variants(scenario, seeds)
    r.timings_s["variants"] = time.perf_counter() - t0
    r.claims = judge(r)
    if extras:
        t = time.perf_counter()
        log("study: the displacement and distance controllers ...")
        r.studies["controller"] = studies.controller_study(scenario, seeds)
        log("study: the estimator ...")
        r.studies["estimator"] = studies.estimator_study(
            [
                ("paper, link 1–2 failed", scenario),
                ("paper, every link Bernoulli 0.3", with_loss(scenario, "bernoulli", 0.3)),
                ("henneberg 20 (2n − 3 edges), every link Bernoulli 0.1", _grid_team(scenario)),
            ],
            seeds,
        )
        log("study: the blend's alpha ...")
        r.studies["alpha"] = studies.alpha_study(scenario, seeds)
        log("study: a changing team (agents leave and join) ...")
        r.studies["dynamic"] = studies.dynamic_study(scenario, seeds)
        r.timings_s["studies"] = time.perf_counter() - t
    if figures:
        t = time.perf_counter()
        log("figures ...")
        write_figures(r, out)
        r.timings_s["figures"] = time.perf_counter() - t
    if real:
        t = time.perf_counter()
        run_real(r, out, record=record, log=log)
        r.timings_s["real processes"] = time.perf_counter() - t
    (out / "seeds.csv").write_text(seeds_csv(r))
    (out / "results.md").write_text(results_markdown(r))
    return r


def _grid_team(paper: Scenario) -> Scenario:
    """A 20-agent minimally rigid team with every link lossy (the scenario files are not needed)."""
    team = henneberg_team(20, seed=1)
    return with_loss(team, "bernoulli", 0.1)


__all__ = [
    "FIGURES",
    "SKIPPED_NOTE",
    "check_recording",
    "representative_seed",
    "run_events_real",
    "run_paper",
    "run_real",
    "write_figures",
]
