"""``report.md``, ``summary.json`` and PNG figures for one run or several runs compared.

:func:`write_report` reads a recording (what ``formation run`` calls at the end);
:func:`write_report_from` takes :class:`analysis.RunData` from anywhere,
e.g. ``simulate(...).record()`` for the in-process simulator. The numbers are
:func:`analysis.summarise`'s.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from analysis import RunData, robot_counts_line, run_team_errors, safety_lines, summarise
from formation.rigidity import expected_rigidity_rank
from recorder.reading.run import read_run
from recorder.reporting import plots
from recorder.reporting.deadlines import deadline_lines, read_deadlines

LISTED_LINKS = 20  # links named in report.md; past that, the ones with most drops

FIGURES = {
    "errors": "Formation and shape error",
    "trajectories": "Trajectories, formation drawn at chosen epochs",
    "links": "Per-link delivered / dropped timeline",
    "topology": "MST changes, rigidity rank and components",
    "covariance": "Substitution and estimation error covariance",
    "nees": "NEES (normalised estimation error squared)",
}
OPTIONAL_FIGURES = {"queues": "Capacity queues: depth over time"}  # runs with capacity only


_CHANGE = {
    "lost": "lost",
    "back": "back",
    "leave": "leaves (scenario event)",
    "crash": "crashes (scenario event)",
    "join": "joins (scenario event)",
    "restart": "restarts (scenario event)",
}


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


def queue_lines(label: str, queues: dict[str, Any], losses: dict[str, int]) -> list[str]:
    """A run's queues as a table, and its losses split by where they happened."""
    lines = [
        f"- {label}: losses {losses['channel']} channel, {losses['queue']} queue (full), "
        f"{losses['deadline']} deadline (left the queue late)",
        "",
        "| queue | offered/epoch | through/epoch | mean depth | max depth | mean sojourn [ms] "
        "| drops by reason |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name, q in queues.items():
        drops = ", ".join(f"{k} {v}" for k, v in q["drops"].items()) or "none"
        lines.append(
            f"| {name} | {q['offered_per_epoch']:.2f} | {q['throughput_per_epoch']:.2f} | "
            f"{_fmt(q['mean_depth'])} | {_fmt(q['max_depth'])} | {_fmt(q['mean_sojourn_ms'])} "
            f"| {drops} |"
        )
    return [*lines, ""]


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
    ended = [(s["label"], why) for s in sums for why in s.get("ended", [])]
    if ended:
        lines += ["", "## How the run ended", ""]
        lines += [f"- {label}: ended early, a plug-in failed: {why}" for label, why in ended]
    lines += ["", "## Numbers", "", "| | " + " | ".join(s["label"] for s in sums) + " |"]
    lines.append("|---|" + "---|" * len(sums))
    for name, key in _ROWS:
        lines.append(f"| {name} | " + " | ".join(_fmt(s[key]) for s in sums) + " |")
    lines += ["", "## Drops per link (longest outage in epochs)", ""]
    for s in sums:
        links = list(s["drops"].items())
        worst = sorted(links, key=lambda kv: -kv[1])[:LISTED_LINKS]  # stable: ties keep order
        shown = links if len(links) <= LISTED_LINKS else worst
        drops = ", ".join(f"{k}: {v} ({s['longest_outage'][k]})" for k, v in shown)
        if len(links) > LISTED_LINKS:
            total = sum(v for _, v in links)
            drops = (
                f"{total} drops on {len(links)} links (every link in summary.json); "
                f"the {LISTED_LINKS} with most: {drops}"
            )
        lines.append(f"- {s['label']}: {drops or 'none'}")
    queued = [s for s in sums if "queues" in s]
    if queued:
        lines += ["", "## Capacity queues", ""]
        for s in queued:
            lines += queue_lines(s["label"], s["queues"], s["loss_split"])
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
    lines += _robot_lines(sums)
    lines += ["", "## Safety", ""]
    for s in sums:
        lines += safety_lines(s["label"], s["safety"])
    lines += _team_lines(sums)
    if notes:
        lines += ["", "## Notes", ""] + [f"- {n}" for n in notes]
    lines += ["", "## Figures", ""]
    for name, file in figures.items():
        title = {**FIGURES, **OPTIONAL_FIGURES}[name]
        lines += [f"### {title}", "", f"![{title}]({file})", ""]
    return "\n".join(lines)


def _robot_lines(sums: list[dict[str, Any]]) -> list[str]:
    """Robot bodies: the errors above are of their measured poses; each one's tracking."""
    tracked = [s for s in sums if "tracking" in s or "robot_counts" in s]
    if not tracked:
        return []
    lines = [
        "",
        "## Robots",
        "",
        "The errors, the trajectories and the safety counts are of the robots' measured poses "
        "(as recorded); the tracking error is a robot's pose against its agent's state.",
        "",
    ]
    for s in tracked:
        if "robot_counts" in s:
            lines.append(f"- {s['label']}: {robot_counts_line(s['robot_counts'])}")
        t = s.get("tracking", {"robots": {}, "warning": None})
        for i, e in t["robots"].items():
            lines.append(
                f"- {s['label']}: robot {i}: tracking error final {e['final_m']:.4g} m, "
                f"peak {e['peak_m']:.4g} m, RMS {e['rms_m']:.4g} m"
            )
        if t["warning"]:
            lines.append(f"- {s['label']}: **{t['warning']}**")
    return lines


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
    sums = [summarise(r) for r in runs]
    files = {
        "errors": plots.plot_errors(
            [(r.label, *run_team_errors(r)) for r in runs],
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
            s.reference_agent,
            chosen,
            out_dir / "trajectories.png",
        ),
        "links": plots.plot_link_timeline(
            [(r.label, r.delivered, r.decided) for r in runs],
            links,
            out_dir / "links.png",
        ),
        "topology": plots.plot_topology(
            [(r.label, r.tree, r.rigidity_rank, r.components, r.rigid) for r in runs],
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
    queued = [(x["label"], x["queues"]) for x in sums if x.get("queues")]
    if queued:  # capacity (docs/model.md §9)
        files["queues"] = plots.plot_queue_depths(queued, out_dir / "queues.png")
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
    run.deadlines = read_deadlines(mcap_path.parent)
    return write_report_from([run], out_dir or mcap_path.parent, title=f"Report: {mcap_path}")


def write_reports(paths: Sequence[Path], out_dir: Path | None = None) -> Path:
    """Several recordings (e.g. one per strategy) compared in one report."""
    runs = [read_run(Path(p)) for p in paths]
    for run, p in zip(runs, paths, strict=True):
        run.deadlines = read_deadlines(Path(p).parent)
    target = out_dir or Path(paths[0]).parent
    return write_report_from(runs, target, title="Report: " + ", ".join(str(p) for p in paths))


__all__ = ["FIGURES", "OPTIONAL_FIGURES", "write_report", "write_report_from", "write_reports"]
