"""``results.md`` and ``seeds.csv`` of ``formation experiment paper``: text only, deterministic.

Every table is a function of the measured runs and the seeds (no run ids, no times), so the same
experiment writes the same bytes.
"""

from __future__ import annotations

import csv
import io
from typing import Any

import numpy as np

from formation.markdown import table
from testbed.experiments.findings import conclusion
from testbed.experiments.grid import KEEP_FRACTION
from testbed.experiments.paper import (
    LOSSY_P,
    SECOND_LINK,
    PaperResults,
    final_errors,
    per_seed_trace,
    window_trace,
)
from testbed.experiments.studies import (
    KEEP_M,
    AlphaStudy,
    ControllerStudy,
    DynamicStudy,
    EstimatorStudy,
    fmt,
    mean_std,
)
from testbed.sim.batch import BatchResult


def _strategy_table(runs: dict[str, BatchResult], epochs_label: str) -> str:
    header = ["strategy", f"final formation error at {epochs_label} [m]", "final shape error [m]"]
    header += ["peak formation error [m]", "tr Cov(x̃ − x), pooled [m²]"]
    header += ["substitutions per seed", "fallbacks per seed"]
    rows = []
    for s, res in runs.items():
        subs = np.bincount(res.sub_member, minlength=res.size)
        rows.append(
            [
                s,
                mean_std(final_errors(res)),
                mean_std(res.shape_error[-1]),
                mean_std(res.formation_error.max(axis=0)),
                fmt(window_trace(res, 0)),
                fmt(float(subs.mean()), ".1f"),
                fmt(float(res.fallbacks.mean()), ".1f"),
            ]
        )
    return table(header, rows)


def seeds_csv(r: PaperResults) -> str:
    """One row per variant × strategy × seed."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(
        [
            "variant",
            "strategy",
            "seed",
            "epochs",
            "final_formation_error_m",
            "final_shape_error_m",
            "peak_formation_error_m",
            "substitution_cov_trace_m2",
            "substitutions",
            "fallbacks",
        ]
    )
    for variant, per in r.runs.items():
        for s, res in per.items():
            traces = per_seed_trace(res)
            subs = np.bincount(res.sub_member, minlength=res.size)
            for b, seed in enumerate(r.seeds):
                w.writerow(
                    [
                        variant,
                        s,
                        seed,
                        res.plan.epochs,
                        format(float(res.formation_error[-1, b]), ".9g"),
                        format(float(res.shape_error[-1, b]), ".9g"),
                        format(float(res.formation_error[:, b].max()), ".9g"),
                        format(float(traces[b]), ".9g"),
                        int(subs[b]),
                        int(res.fallbacks[b]),
                    ]
                )
    return buf.getvalue()


FIGURE_CAPTIONS = {
    "formation_error_failure.png": "Formation error when link 1–2 fails, median (line) and 10–90 % "
    "of the seeds (band), log scale",
    "formation_error_500.png": "The same for 500 epochs: `zero` and `hold` drift away as the team "
    "moves, the others stay at the noise floor",
    "formation_error_one_lossy.png": f"Formation error with link 1–2 lossy (Bernoulli {LOSSY_P:g})",
    "formation_error_two_lossy.png": f"Formation error with links 1–2 and {SECOND_LINK[0]}–"
    f"{SECOND_LINK[1]} lossy (Bernoulli {LOSSY_P:g})",
    "positions.png": "x and y of agents 3 and 5 over the epochs, one column per strategy, the "
    "slots they should hold in grey (the chapter's figs 7.7–7.11), first seed",
    "trajectories.png": "The same agents' paths in the plane, their slots in grey, first seed",
    "substitution_covariance.png": "Trace of the covariance of the values used for lost packets "
    "minus the truth, at each epoch over the seeds",
}
LEGEND_NOTE = (
    "Each strategy has one colour, line style and marker in every figure; the dashed grey line "
    "is the keep threshold, the dotted one the noise floor (`drop`'s mean final error, when it "
    "keeps the formation); a strategy identical to another is drawn over it with its markers "
    "at other epochs, and its legend says so."
)


def _figure(name: str, caption: str) -> list[str]:
    alt = caption.split(",")[0].split(". ")[0]
    return [f"![{alt}]({name})", "", f"*{caption}.*", ""]


def results_markdown(r: PaperResults) -> str:
    """The whole ``results.md``: the conclusion and its figure, the claims, each variant's
    table, the studies, the real runs, the other figures."""
    fail = r.runs["failure"]
    key = "formation_error_failure.png"
    out = [
        f"# {r.scenario.name}: the chapter's experiment over {len(r.seeds)} seeds",
        "",
        " ".join(conclusion(fail)),
        "",
        *_figure(key, FIGURE_CAPTIONS[key] + ". " + LEGEND_NOTE.removesuffix(".")),
        *_setup(r),
        *_claims(r),
        *_variants(r),
    ]
    extra = r.studies
    sections = (
        ("controller", _controller),
        ("estimator", _estimator),
        ("alpha", _alpha),
        ("dynamic", lambda d: _dynamic(d, real=bool(r.real))),
    )
    for name, section in sections:
        if name in extra:
            out += section(extra[name])
    if r.real:
        out += _real(r.real)
    out += ["", "## Other figures", ""]
    for name, caption in FIGURE_CAPTIONS.items():
        if name != key:
            out += _figure(name, caption)
    out.append("Every number per seed: `seeds.csv` (a row per variant, strategy and seed).")
    return "\n".join(out) + "\n"


def _setup(r: PaperResults) -> list[str]:
    s, seeds = r.scenario, r.seeds
    return [
        "## How it was run",
        "",
        f"`formation experiment paper` on the scenario `{s.name}` (docs/model.md §8): {s.n} "
        f"agents, link 1–2 down from epoch 1, reference moving along a line, noise σ = "
        f"{s.noise.sigma_m:g} m, ε = {s.control.epsilon:g}; {len(seeds)} seeds ({seeds[0]}–"
        f"{seeds[-1]}), {s.epochs} epochs as in the chapter and 500 for steady state. Every "
        "variant is simulated in-process, a batch over the seeds, which equals `formation "
        "simulate` seed by seed (the last section runs real processes). Mean ± standard "
        f"deviation over the seeds. A run keeps the formation when its final formation error "
        f"is under {KEEP_M:g} m.",
        "",
    ]


def _claims(r: PaperResults) -> list[str]:
    claims = table(
        ["source", "claim", "verdict", "numbers"],
        ([c.source, c.text, f"**{c.verdict}**", c.evidence] for c in r.claims),
    )
    return ["## The chapter's claims", "", claims.rstrip("\n")]


def _variants(r: PaperResults) -> list[str]:
    s = r.scenario
    titles = {
        "failure": f"Link 1–2 fails (figs 7.7–7.11), {s.epochs} epochs",
        "failure, 500 epochs": "Link 1–2 fails, 500 epochs (steady state)",
        "one lossy link": f"One lossy link: 1–2 with Bernoulli loss {LOSSY_P:g} for all {s.epochs} epochs",
        "two lossy links": f"Two lossy links: 1–2 and {SECOND_LINK[0]}–{SECOND_LINK[1]}, Bernoulli loss {LOSSY_P:g}",
    }
    out: list[str] = []
    for variant, per in r.runs.items():
        epochs = per["estimate"].plan.epochs
        out += ["", f"## {titles.get(variant, variant)}", ""]
        if variant != "failure":  # the failure's conclusion opens the file
            out += [" ".join(conclusion(per)), ""]
        out.append(_strategy_table(per, f"epoch {epochs}"))
    return [
        *out,
        "Substitution errors (docs/model.md §7) count every lost variable, also those the "
        "reference agent fills in without steering by them (it follows the reference).",
    ]


def _controller(c: ControllerStudy) -> list[str]:
    return [
        "",
        "## §7.2: rigidity or connectivity (controller table)",
        "",
        f"Links dropped in both directions for all {c.epochs} epochs, strategy `drop` (the lost terms left "
        f"out, so the controller runs on the healthy graph), no other loss, {len(c.seeds)} seeds; kept = "
        f"final formation error < {KEEP_M:g} m in ≥ {KEEP_FRACTION:.0%} of seeds. The distance gain is "
        "lower because the distance law is unstable at the displacement law's gain (it diverged at 0.25).",
        "",
        c.markdown(),
        f"§7.2 argument {'**held**' if c.holds() else '**not held**'}: every case is kept exactly when "
        "the controller's graph condition (rigid for distance, connected for displacement) holds."
        if c.holds()
        else "§7.2 argument **not held** in at least one case above.",
    ]


def _estimator(e: EstimatorStudy) -> list[str]:
    return [
        "",
        "## BLUE on the Kruskal tree vs on every healthy edge",
        "",
        f"Strategy `estimate`, {e.epochs} epochs, {len(e.seeds)} seeds. Predicted: mean over epochs and "
        "observable followers of tr Cov(x̂_i); empirical: trace of the covariance of the pooled errors "
        "x̂_i − x_i. NEES averages d = 2 for an honest estimator.",
        "",
        e.markdown(),
    ]


def _alpha(a: AlphaStudy) -> list[str]:
    return [
        "",
        "## α of blend",
        "",
        f"{len(a.seeds)} seeds; α = 1 is `estimate`; in brackets the value relative to α = 1. The best α "
        "depends on the window: a small α averages more noise but lags the consensus transient longer.",
        "",
        a.markdown(),
        "![alpha](alpha.png)",
    ]


def _dynamic(d: DynamicStudy, real: bool) -> list[str]:
    (la, ka), (lj, kj) = d.leave, d.join
    return [
        "",
        "## Dynamic formation: an agent leaves, another joins",
        "",
        f"`{d.scenario.name}`: the pentagon plus agent {lj} (edges 3–{lj}, 4–{lj}), link 1–2 down as in the "
        f"paper. Agent {la} leaves at epoch {ka} (its links stop, it leaves the consensus, the tree and the "
        f"estimate, and stays where it is); agent {lj} joins at epoch {kj} from where it was parked. Shape "
        f"error over the edges active at each epoch, median of {len(d.seeds)} seeds. The leader's tree has "
        f"{int(d.tree_edges[ka - 1])} edges before epoch {ka}, {int(d.tree_edges[ka])} after agent {la} "
        f"leaves and {int(d.tree_edges[kj])} after agent {lj} joins; observable agents "
        f"{int(d.observable[ka - 1])} → {int(d.observable[ka])} → {int(d.observable[kj])}."
        + (
            " The same leave and join as scenario events also run through real processes (the "
            'last row of "Real processes" below, with `real_runs.md`).'
            if real
            else ""
        ),
        "",
        d.markdown(),
        "![dynamic](dynamic.png)",
    ]


def _real(real: list[dict[str, Any]]) -> list[str]:
    header = ["strategy", "seed", "simulated final formation error [m]", "real [m]"]
    header += ["max abs position difference [m]", "recorded positions max abs difference [m]"]
    rows = (
        [
            row["strategy"],
            row["seed"],
            fmt(row["sim_final"], ".6g"),
            fmt(row.get("real_final", float("nan")), ".6g"),
            row.get("max_diff_text", "-"),
            row.get("recorded_diff_text", "-"),
            row.get("match", "no"),
        ]
        for row in real
    )
    return [
        "",
        "## Real processes",
        "",
        "One representative seed per strategy (the seed whose final formation error is closest to the "
        "median over the seeds) run through the real processes (`formation run`: router, recorder, netem, "
        "leader, agents over Zenoh, lockstep); positions compared with the simulation epoch by epoch. "
        "Run ids and wall times: `real_runs.md`.",
        "",
        table([*header, "match"], rows).rstrip("\n"),
    ]


__all__ = ["FIGURE_CAPTIONS", "LEGEND_NOTE", "results_markdown", "seeds_csv"]
