"""``report.md``, ``summary.json`` and PNG figures for one run or several runs compared.

:func:`write_report` reads a recording (what ``formation run`` calls at the end);
:func:`write_report_from` takes :class:`~recorder.rundata.RunData` from anywhere,
e.g. ``RunData.from_result(simulate(...))`` for the in-process simulator. The
numbers are those of docs/model.md §7, recomputed from the arrays.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from formation.graph import expected_rigidity_rank
from recorder import membership, plots
from recorder.deadlines import deadline_lines, read_deadlines
from recorder.metrics import error_statistics, longest_run
from recorder.rundata import RunData, read_run
from recorder.safety import safety_counts, safety_lines

FIGURES = {
    "errors": "Formation and shape error",
    "trajectories": "Trajectories, formation drawn at chosen epochs",
    "links": "Per-link delivered / dropped timeline",
    "topology": "MST changes, rigidity rank and components",
    "covariance": "Substitution and estimation error covariance",
    "nees": "NEES (normalised estimation error squared)",
}


def _last_finite(values: np.ndarray) -> float | None:
    finite = values[np.isfinite(values)]
    return float(finite[-1]) if finite.size else None


def _peak(values: np.ndarray) -> float | None:
    finite = values[np.isfinite(values)]
    return float(finite.max()) if finite.size else None


def _num(v: float) -> float | None:
    return None if v is None or not math.isfinite(v) else float(v)


def summarize(run: RunData) -> dict[str, Any]:
    """The headline numbers of a run (docs/model.md §7); None where the run has no data."""
    s = run.scenario
    links = [f"{a}->{b}" for a, b in run.links]
    lost = run.decided & ~run.delivered
    _, _, sub_trace = error_statistics(run.substitution_errors)
    _, _, est_trace = error_statistics(run.estimation_errors)
    known = run.rigidity_rank >= 0
    tree = run.tree[known]
    expected = expected_rigidity_rank(s.n, s.dimension)
    out: dict[str, Any] = {
        "label": run.label,
        "source": run.source,
        "scenario": s.name,
        "strategy": run.strategy,
        "seed": run.seed,
        "epochs_with_states": int(np.isfinite(run.positions).all(axis=(1, 2)).sum()),
        "epochs_with_estimates": int(known.sum()),
        # with an agent out, over the team taking part (as drawn), not the last full epoch
        "final_formation_error_m": _last_finite(_team_formation(run)),
        "peak_formation_error_m": _peak(run.formation_error),
        "final_shape_error_m": _last_finite(_team_shape(run)),
        "peak_shape_error_m": _peak(run.shape_error),
        "substitutions": int(run.substitution_errors.shape[0]),
        "substitution_cov_trace_m2": _num(sub_trace),
        "estimation_cov_trace_m2": _num(est_trace),
        "nees_mean": _num(float(run.nees_values.mean())) if run.nees_values.size else None,
        "nees_expected": s.dimension,
        "covariance_every": s.estimator.covariance_every,
        "drops": {links[c]: int(v) for c, v in enumerate(lost.sum(axis=0)) if v},
        "longest_outage": {
            links[c]: longest_run(lost[:, c]) for c in range(len(links)) if lost[:, c].any()
        },
        "tree_changes": int((tree[1:] != tree[:-1]).any(axis=1).sum()) if len(tree) > 1 else 0,
        "epochs_not_rigid": int((run.rigidity_rank[known] < expected).sum()),
        "expected_rigidity_rank": expected,
        "epochs_split": int((run.components[known] > 1).sum()),
    }
    skipped = run.extra.get("skipped")
    if skipped is not None:
        out["skipped"] = skipped.as_json()
    if (timed := run.extra.get("deadlines")) is not None:
        out["deadlines"] = timed
    out.update(_team(run))
    out["safety"] = safety_counts(s, run.positions, run.headings, run.saturated)
    recorded = run.extra.get("recorded_formation_error")
    if recorded is not None and np.isfinite(recorded).any():
        both = np.isfinite(recorded) & np.isfinite(run.formation_error)
        gap = np.abs(recorded[both] - run.formation_error[both])
        out["recorded_metrics_max_gap_m"] = float(gap.max()) if gap.size else None
    return out


def _team(run: RunData) -> dict[str, Any]:
    """Who was in the team at each epoch, when it changed, and the transient after each."""
    team = membership.present(run.positions)
    if team.all() or not team.any():
        return {}
    shape = membership.team_shape_error(
        run.positions, run.scenario.edge_array, run.scenario.offsets
    )
    events = [(e.epoch, e.agent, e.action) for e in run.scenario.events]
    return {
        "team": {str(i): s for i, s in membership.spans(team).items()},
        "team_changes": [vars(c) for c in membership.changes(team, shape, events=events)],
        "shape_threshold_m": membership.SHAPE_THRESHOLD_M,
    }


def _team_shape(run: RunData) -> np.ndarray:
    """The shape error, over the edges between present agents where some agent is absent."""
    team = membership.team_shape_error(run.positions, run.scenario.edge_array, run.scenario.offsets)
    return np.where(_someone_out(run), team, run.shape_error)


def _team_formation(run: RunData) -> np.ndarray:
    """The formation error, likewise (:func:`_team_shape`)."""
    s = run.scenario
    team = membership.team_formation_error(run.positions, s.edge_array, s.weights)
    return np.where(_someone_out(run), team, run.formation_error)


def _someone_out(run: RunData) -> np.ndarray:
    """(E + 1,) some agent has no recorded state at the epoch, and some has."""
    present = membership.present(run.positions)
    return np.asarray(~present.all(axis=1) & present.any(axis=1), dtype=bool)


_CHANGE = {"lost": "lost", "back": "back", "leave": "leaves (scenario event)",
           "crash": "crashes (scenario event)", "join": "joins (scenario event)",
           "restart": "restarts (scenario event)"}  # fmt: skip


def _team_lines(sums: list[dict[str, Any]]) -> list[str]:
    if not any("team" in s for s in sums):
        return []
    lines = ["", "## Team", ""]
    for s in sums:
        if "team" not in s:
            lines.append(f"- {s['label']}: every agent at every epoch")
            continue
        spans = "; ".join(
            f"{i}: " + ", ".join(f"{a}–{b}" for a, b in v) for i, v in s["team"].items()
        )
        lines.append(f"- {s['label']}: agent: epochs in the team — {spans}")
        for c in s["team_changes"]:
            t = c["transient_epochs"]
            back = "never" if t is None else f"after {t} epochs"
            lines.append(
                f"  - epoch {c['epoch']}: agent {c['agent']} {_CHANGE[c['what']]}; shape error "
                f"under {s['shape_threshold_m']:g} m {back}"
            )
    return lines


def _fmt(v: Any) -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


_ROWS = (
    ("epochs with all states", "epochs_with_states"),
    ("epochs with an estimate", "epochs_with_estimates"),
    ("final formation error [m]", "final_formation_error_m"),
    ("peak formation error [m]", "peak_formation_error_m"),
    ("final shape error [m]", "final_shape_error_m"),
    ("peak shape error [m]", "peak_shape_error_m"),
    ("substitutions", "substitutions"),
    ("substitution error cov. trace [m²]", "substitution_cov_trace_m2"),
    ("estimation error cov. trace [m²]", "estimation_cov_trace_m2"),
    ("NEES mean (expected d)", "nees_mean"),
    ("MST changes", "tree_changes"),
    ("epochs not rigid", "epochs_not_rigid"),
    ("epochs split (components > 1)", "epochs_split"),
)


def _markdown(
    title: str, runs: Sequence[RunData], sums: list[dict[str, Any]], figures: dict[str, str]
) -> str:
    lines = [f"# {title}", ""]
    for run in runs:
        lines.append(
            f"- **{run.label}**: `{run.source}` (scenario {run.scenario.name}, seed {run.seed})"
        )
    lines += ["", "## Numbers", "", "| | " + " | ".join(s["label"] for s in sums) + " |"]
    lines.append("|---|" + "---|" * len(sums))
    for name, key in _ROWS:
        lines.append(f"| {name} | " + " | ".join(_fmt(s[key]) for s in sums) + " |")
    lines += ["", "## Drops per link (longest outage in epochs)", ""]
    for s in sums:
        drops = ", ".join(f"{k}: {v} ({s['longest_outage'][k]})" for k, v in s["drops"].items())
        lines.append(f"- {s['label']}: {drops or 'none'}")
    timed = [(run, s["deadlines"]) for run, s in zip(runs, sums, strict=True) if "deadlines" in s]
    if timed:
        lines += ["", "## Realtime: modelled losses and deadline misses", ""]
        for run, d in timed:
            lines += deadline_lines(run.label, d)
    notes = []
    for run, s in zip(runs, sums, strict=True):
        every = s["covariance_every"]
        if every > 1:
            notes.append(
                f"{run.label}: the leader computed covariances every {every} epochs "
                f"(estimator.covariance_every = {every}); NEES and the estimation error "
                "covariance are over those epochs only."
            )
        gap = s.get("recorded_metrics_max_gap_m")
        if gap is not None:
            notes.append(
                f"{run.label}: the recorder's live metrics match the recomputed ones within {gap:.3g} m."
            )
    skips = [(run, s["skipped"]) for run, s in zip(runs, sums, strict=True) if "skipped" in s]
    if skips:
        lines += ["", "## Messages not trusted", ""]
        lines.append(
            "Every recorded message is validated against its model and its sender checked "
            "against the key's owner, the scenario's epochs and agents; these were skipped:"
        )
        lines.append("")
        for run, sk in skips:
            if not sk["total"]:
                lines.append(f"- {run.label}: none")
                continue
            reasons = ", ".join(f"{r} {v}" for r, v in sk["by_reason"].items())
            lines.append(f"- {run.label}: {sk['total']} ({reasons})")
            for topic, by_reason in sk["by_channel"].items():
                what = ", ".join(f"{r} {v}" for r, v in by_reason.items())
                lines.append(f"  - `{topic}`: {what}")
    lines += ["", "## Safety", ""]
    for s in sums:
        lines += safety_lines(s["label"], s["safety"])
    lines += _team_lines(sums)
    if notes:
        lines += ["", "## Notes", ""] + [f"- {n}" for n in notes]
    lines += ["", "## Figures", ""]
    for name, file in figures.items():
        lines += [f"### {FIGURES[name]}", "", f"![{FIGURES[name]}]({file})", ""]
    return "\n".join(lines)


def write_report_from(runs: Sequence[RunData], out_dir: Path, title: str | None = None) -> Path:
    """Figures, ``report.md`` and ``summary.json`` in ``out_dir`` for ``runs`` (compared on shared axes)."""
    if not runs:
        raise ValueError("write_report_from needs at least one run")
    out_dir.mkdir(parents=True, exist_ok=True)
    first = runs[0]
    s = first.scenario
    links = [f"{a}→{b}" for a, b in first.links]
    length = max(len(r.positions) for r in runs)
    chosen = sorted({0, length // 4, length // 2, max(length - 1, 0)})
    sums = [summarize(r) for r in runs]
    files = {
        "errors": plots.plot_errors(
            [(r.label, _team_formation(r), _team_shape(r)) for r in runs],
            out_dir / "errors.png",
            marks=[
                (c["epoch"], f"{c['what']} {c['agent']}")
                for x in sums
                for c in x.get("team_changes", [])
            ],
        ),
        "trajectories": plots.plot_trajectories(
            [(r.label, r.positions) for r in runs],
            s.edge_array,
            s.leader,
            chosen,
            out_dir / "trajectories.png",
        ),
        "links": plots.plot_link_timeline(
            [(r.label, r.delivered, r.decided) for r in runs],
            links,
            out_dir / "links.png",
        ),
        "topology": plots.plot_topology(
            [(r.label, r.tree, r.rigidity_rank, r.components) for r in runs],
            expected_rigidity_rank(s.n, s.dimension),
            out_dir / "topology.png",
        ),
        "covariance": plots.plot_covariance(
            [(r.label, r.substitution_errors, r.estimation_errors) for r in runs],
            out_dir / "covariance.png",
        ),
        "nees": plots.plot_nees(
            [(r.label, r.nees_values) for r in runs], s.dimension, out_dir / "nees.png"
        ),
    }
    (out_dir / "summary.json").write_text(json.dumps(sums, indent=2) + "\n", encoding="utf-8")
    title = title or f"Report: {s.name}"
    text = _markdown(title, runs, sums, {k: p.name for k, p in files.items()})
    path = out_dir / "report.md"
    path.write_text(text + "\n", encoding="utf-8")
    return path


def write_report(mcap_path: Path, out_dir: Path | None = None) -> Path:
    """The report of one recording, next to it unless ``out_dir`` is given; returns ``report.md``."""
    mcap_path = Path(mcap_path)
    run = read_run(mcap_path)
    run.extra["deadlines"] = read_deadlines(mcap_path.parent)
    return write_report_from([run], out_dir or mcap_path.parent, title=f"Report: {mcap_path}")


def write_reports(paths: Sequence[Path], out_dir: Path | None = None) -> Path:
    """Several recordings (e.g. one per strategy) compared in one report."""
    runs = [read_run(Path(p)) for p in paths]
    for run, p in zip(runs, paths, strict=True):
        run.extra["deadlines"] = read_deadlines(Path(p).parent)
    target = out_dir or Path(paths[0]).parent
    return write_report_from(runs, target, title="Report: " + ", ".join(str(p) for p in paths))


__all__ = ["FIGURES", "summarize", "write_report", "write_report_from", "write_reports"]
