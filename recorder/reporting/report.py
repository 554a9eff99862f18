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

import numpy as np

from analysis import (
    RunData,
    robot_counts_line,
    run_team_errors,
    safety_lines,
    summarise,
    tracking_lines,
)
from formation.markdown import table
from formation.rigidity import expected_rigidity_rank
from recorder.reading.run import read_run
from recorder.reporting import network_plots, plots
from recorder.reporting.conclusion import KEEP_M, coincidence_notes, conclusion, names
from recorder.reporting.deadlines import deadline_lines, read_deadlines
from recorder.reporting.plots import Drawn
from recorder.reporting.style import look

LISTED_LINKS = 20  # links named in report.md; past that, the ones with most drops

FIGURES = {
    "errors": "Formation and shape error",
    "trajectories": "Trajectories, formation drawn at chosen epochs",
    "links": "Each link's packets: delivered, dropped, unknown",
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
    header = (
        "queue",
        "offered/epoch",
        "through/epoch",
        "mean depth",
        "max depth",
        "mean sojourn [ms]",
        "drops by reason",
    )
    rows = [
        (
            name,
            f"{q['offered_per_epoch']:.2f}",
            f"{q['throughput_per_epoch']:.2f}",
            _fmt(q["mean_depth"]),
            _fmt(q["max_depth"]),
            _fmt(q["mean_sojourn_ms"]),
            ", ".join(f"{k} {v}" for k, v in q["drops"].items()) or "none",
        )
        for name, q in queues.items()
    ]
    return [
        f"- {label}: losses {losses['channel']} channel, {losses['queue']} queue (full), "
        f"{losses['deadline']} deadline (left the queue late)",
        "",
        *table(header, rows).splitlines(),
        "",
    ]


def air_lines(label: str, air: dict[str, Any]) -> list[str]:
    """A run's packets on the air per link class: delivered, and losses by cause."""
    header = (
        "link class",
        "took the air",
        "delivered",
        "losses by cause",
        "mean arrival [ms]",
        "max arrival [ms]",
    )
    rows = [
        (
            cls,
            a["took_air"],
            a["delivered"],
            ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in a["losses"].items()) or "none",
            _fmt(a["mean_arrival_ms"]),
            _fmt(a["max_arrival_ms"]),
        )
        for cls, a in air.items()
    ]
    return [
        f"- {label}: of the packets the link models passed, what the air delivered and why "
        "it lost the others",
        "",
        *table(header, rows).splitlines(),
        "",
    ]


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


FOOTNOTES = {
    "epochs not rigid": "epochs whose healthy graph (the links that delivered) is not rigid: "
    "only the distance controller needs rigidity; displacement consensus needs the graph "
    "connected (the row below).",
    "NEES mean (expected d)": "normalised estimation error squared of each agent's position "
    "estimate; an honest estimator averages d, the dimension (nees.png has its χ² band).",
    "substitutions": "lost packets an agent filled in (`drop` leaves them out, so it has none).",
}


def _numbers(columns: Sequence[str], sums: list[dict[str, Any]]) -> list[str]:
    """The table of :data:`_ROWS`, a column per run, and its footnotes."""
    notes = [name for name, _ in _ROWS if name in FOOTNOTES]
    mark = {name: f" [{i}]" for i, name in enumerate(notes, 1)}
    rows = [(f"{name}{mark.get(name, '')}", *(_fmt(s[key]) for s in sums)) for name, key in _ROWS]
    lines = [*table(("", *columns), rows).splitlines(), ""]
    lines += [f"[{i}] {FOOTNOTES[name]}  " for i, name in enumerate(notes, 1)]
    return lines


def _runs(runs: Sequence[RunData]) -> list[str]:
    """Where each run comes from: its recording, or the simulator."""
    lines = []
    for run in runs:
        where = f"`{run.source}`" if run.recorded is not None else "simulated in-process"
        lines.append(
            f"- **{run.label}**: {where} (scenario {run.scenario.name}, strategy "
            f"{run.strategy}, seed {run.seed})"
        )
    return lines


def _markdown(
    title: str,
    runs: Sequence[RunData],
    sums: list[dict[str, Any]],
    figures: dict[str, str],
    captions: dict[str, str],
) -> str:
    lines = [f"# {title}", "", " ".join(conclusion(runs)), ""]
    key = "errors"
    lines += [f"![{FIGURES[key]}]({figures[key]})", "", f"*{captions[key]}*", ""]
    ended = [(s["label"], why) for s in sums for why in s.get("ended", [])]
    if ended:
        lines += ["## How the run ended", ""]
        lines += [f"- {label}: ended early, a plug-in failed: {why}" for label, why in ended]
        lines.append("")
    lines += ["## Numbers", "", *_numbers(names(runs), sums), "", "## Runs", "", *_runs(runs)]
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
    aired = [s for s in sums if "air" in s]
    if aired:
        lines += ["", "## The shared air", ""]
        for s in aired:
            lines += air_lines(s["label"], s["air"])
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
        if name == key:
            continue
        title = {**FIGURES, **OPTIONAL_FIGURES}[name]
        lines += [f"### {title}", "", f"![{title}]({file})", "", f"*{captions[name]}*", ""]
    return "\n".join(lines)


def _drawn(runs: Sequence[RunData]) -> list[Drawn]:
    """Each run's name and look: its strategy's, or its label's when two share a strategy."""
    strategies = [r.strategy for r in runs]
    notes = coincidence_notes(runs)
    return [
        Drawn(
            name,
            look(r.strategy if strategies.count(r.strategy) == 1 else r.label),
            notes.get(i, ""),
        )
        for i, (r, name) in enumerate(zip(runs, names(runs), strict=True))
    ]


def _floor(runs: Sequence[RunData], sums: list[dict[str, Any]]) -> float | None:
    """The noise floor: ``drop``'s final formation error when it kept the formation (it
    leaves lost terms out, so only the measurement noise is left)."""
    finals = [
        s["final_formation_error_m"]
        for r, s in zip(runs, sums, strict=True)
        if r.strategy == "drop"
    ]
    return finals[0] if finals and finals[0] is not None and finals[0] < KEEP_M else None


def _captions(
    runs: Sequence[RunData], drawn: Sequence[Drawn], floor: float | None, chosen: Sequence[int]
) -> dict[str, str]:
    same = "; ".join(
        f"`{d.label}` is drawn over `{d.note.removeprefix('identical to ')}`: identical to the bit"
        for d in drawn
        if d.note
    )
    floor_text = (
        f", the dotted one the noise floor ({floor:.2g} m: `drop`'s final error, measurement noise only)"
        if floor is not None
        else ""
    )
    s = runs[0].scenario
    return {
        "errors": f"Formation error (top) and shape error (bottom) per epoch, each strategy in its "
        f"own colour, line and marker. The dashed grey line is the {KEEP_M:g} m keep threshold"
        f"{floor_text}." + (f" {same}." if same else ""),
        "trajectories": f"Each run's agents (thin paths) and its formation at epochs "
        f"{', '.join(str(k) for k in chosen)} (dotted grey, then solid in the strategy's colour at "
        f"the last); the target shape dashed, placed on the reference agent {s.reference_agent}; "
        "links down at the last epoch marked ✕.",
        "links": "Every formation link's packets per epoch, drawn once for runs whose links "
        "delivered the same: sky blue delivered, vermillion dropped, grey unknown.",
        "topology": "The leader's view of the links that delivered: its spanning tree's size "
        f"(× where it changed), the rigidity rank against {expected_rigidity_rank(s.n, s.dimension)} "
        "(rigid) and the connected components; one line for runs with the same graph.",
        "covariance": "Left: the value each strategy used for a lost packet minus the truth, with "
        "2σ ellipses. Right: the leader's estimation error, once for runs with the same estimate.",
        "nees": f"NEES of the leader's position estimates against χ²_{s.dimension}: an honest "
        "estimator's running mean stays in the grey 95 % band.",
        "queues": "Each capacity queue's largest depth per epoch [packets].",
    }


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
        told = tracking_lines(t)
        lines += [f"- {s['label']}: {line}" for line in told[: len(t["robots"])]]
        lines += [f"- {s['label']}: **{line}**" for line in told[len(t["robots"]) :]]
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
    chosen = sorted({0, length // 2, max(length - 1, 0)})
    sums = [summarise(r) for r in runs]
    drawn = _drawn(runs)
    floor = _floor(runs, sums)
    failed = ~first.healthy[-1] if len(first.healthy) else np.zeros(len(s.edge_array), bool)
    files = {
        "errors": plots.plot_errors(
            drawn,
            [run_team_errors(r) for r in runs],
            out_dir / "errors.png",
            marks=[
                (c["epoch"], f"{c['what']} {c['agent']}")
                for x in sums
                for c in x.get("team_changes", [])
            ],
            keep_m=KEEP_M,
            floor_m=floor,
        ),
        "trajectories": plots.plot_trajectories(
            drawn,
            [r.positions for r in runs],
            s.edge_array,
            s.offsets,
            s.reference_agent,
            failed,
            chosen,
            out_dir / "trajectories.png",
        ),
        "links": network_plots.plot_link_timeline(
            drawn, [(r.delivered, r.decided) for r in runs], links, out_dir / "links.png"
        ),
        "topology": network_plots.plot_topology(
            drawn,
            [(r.tree, r.rigidity_rank, r.components, r.rigid) for r in runs],
            expected_rigidity_rank(s.n, s.dimension),
            out_dir / "topology.png",
        ),
        "covariance": plots.plot_covariance(
            drawn,
            [r.substitution_errors for r in runs],
            [r.estimation_errors for r in runs],
            out_dir / "covariance.png",
        ),
        "nees": plots.plot_nees(
            drawn, [r.nees_values for r in runs], s.dimension, out_dir / "nees.png"
        ),
    }
    queued = [(d, x["queues"]) for d, x in zip(drawn, sums, strict=True) if x.get("queues")]
    if queued:  # capacity (docs/model.md §9)
        files["queues"] = plots.plot_queue_depths(queued, out_dir / "queues.png")
    (out_dir / "summary.json").write_text(json.dumps(sums, indent=2) + "\n", encoding="utf-8")
    title = title or _title(runs)
    captions = _captions(runs, drawn, floor, chosen)
    text = _markdown(title, runs, sums, {k: p.name for k, p in files.items()}, captions)
    path = out_dir / "report.md"
    path.write_text(text + "\n", encoding="utf-8")
    return path


def _title(runs: Sequence[RunData]) -> str:
    """``paper: estimate, seed 1`` or ``paper: zero, hold and estimate compared, seed 1``."""
    seeds = sorted({r.seed for r in runs})
    seed = f"seed {seeds[0]}" if len(seeds) == 1 else "seeds " + ", ".join(map(str, seeds))
    if len(runs) == 1:
        return f"{runs[0].scenario.name}: {runs[0].strategy}, {seed}"
    names = [r.strategy for r in runs]
    named = ", ".join(names[:-1]) + " and " + names[-1]
    return f"{runs[0].scenario.name}: {named} compared, {seed}"


def write_report(mcap_path: Path, out_dir: Path | None = None) -> Path:
    """The report of one recording, next to it unless ``out_dir`` is given; returns ``report.md``."""
    mcap_path = Path(mcap_path)
    run = read_run(mcap_path)
    run.deadlines = read_deadlines(mcap_path.parent)
    return write_report_from([run], out_dir or mcap_path.parent)


def write_reports(paths: Sequence[Path], out_dir: Path | None = None) -> Path:
    """Several recordings (e.g. one per strategy) compared in one report."""
    runs = [read_run(Path(p)) for p in paths]
    for run, p in zip(runs, paths, strict=True):
        run.deadlines = read_deadlines(Path(p).parent)
    target = out_dir or Path(paths[0]).parent
    return write_report_from(runs, target)


__all__ = [
    "FIGURES",
    "FOOTNOTES",
    "OPTIONAL_FIGURES",
    "write_report",
    "write_report_from",
    "write_reports",
]
