"""The regions of ``formation experiment value``, computed from its cells, and its ``results.md``.

A row of the map is a controller and a case; its verdict compares estimate's judged final
error with drop's and hold's over the seeds (:func:`verdict`), and its reason is computed from
what the run shows: the share of epochs in which the graph ``drop`` leaves was rigid and
connected, estimate's fallbacks to hold, and which strategies gave the same numbers.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import pandas as pd

from formation.markdown import table
from testbed.experiments.value import GAINS, KEEP_M, LOST, ValueSpec

Array = npt.NDArray[np.float64]
PAYS = 2.0  # estimate pays where drop's and hold's mean errors are at least this many times its own
WINS = 0.9  # … and it beats drop in at least this share of the seeds
SAME = 1.25  # drop is as good where the two means are within this factor
LAWS = {
    "displacement": "displacement consensus needs only a connected graph",
    "distance": "the distance law needs a rigid graph",
}


@dataclass(frozen=True)
class Row:
    """One controller and case over the seeds: each strategy's judged final errors (S,)."""

    controller: str
    axis: str
    case: str
    errors: dict[str, Array]
    fallbacks: float  # estimate's fallbacks to hold per run
    rigid_share: float
    connected_share: float
    epochs: int

    def ratio(self, strategy: str) -> Array:
        """(S,) the strategy's error over estimate's, seed by seed."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return self.errors[strategy] / self.errors["estimate"]

    def coinciding(self) -> list[tuple[str, ...]]:
        """Groups of two or more strategies whose errors are equal in every seed, bit for bit."""
        groups: dict[bytes, list[str]] = {}
        for s, e in self.errors.items():
            groups.setdefault(np.asarray(e).tobytes(), []).append(s)
        return [tuple(g) for g in groups.values() if len(g) > 1]


def rows(frame: pd.DataFrame, spec: ValueSpec) -> list[Row]:
    """The map's rows, in the spec's order (controllers, then cases)."""
    out = []
    for controller in spec.controllers:
        for c in spec.cases:
            cells = frame[(frame.controller == controller) & (frame.case == c.label)]
            by = {s: part.sort_values("seed") for s, part in cells.groupby("strategy")}
            est = by["estimate"]
            out.append(
                Row(
                    controller=controller,
                    axis=c.axis,
                    case=c.label,
                    errors={s: by[s]["final_error_m"].to_numpy(float) for s in spec.strategies},
                    fallbacks=float(est["fallbacks"].clip(lower=0).mean()),
                    rigid_share=float(est["rigid_share"].mean()),
                    connected_share=float(est["connected_share"].mean()),
                    epochs=spec.epochs,
                )
            )
    return out


def verdict(row: Row) -> str:
    """``pays``, ``modest`` (estimate best of the three, by less), ``same`` (drop as good) or
    ``worse`` (drop better), from the means over the seeds."""
    est, drop, hold = (float(np.mean(row.errors[s])) for s in ("estimate", "drop", "hold"))
    wins = float(np.mean(row.errors["estimate"] < row.errors["drop"]))
    if drop >= PAYS * est and hold >= PAYS * est and wins >= WINS:
        return "pays"
    if drop * SAME < est:
        return "worse"
    if est * SAME > drop:
        return "same"
    return "modest"


def _m(v: Array) -> str:
    """Mean ± standard deviation over the seeds [m]; the diverged seeds counted apart."""
    v = np.asarray(v, dtype=float)
    finite = v[np.isfinite(v)]
    if not finite.size:
        return "diverged in every seed"
    text = f"{np.mean(finite):.3g} ± {np.std(finite):.2g} m"
    return text + (
        f" ({v.size - finite.size} of {v.size} diverged)" if finite.size < v.size else ""
    )


def _times(r: Array) -> str:
    finite = r[np.isfinite(r)]
    if not finite.size:
        return "diverged"
    text = f"{np.mean(finite):.3g} ± {np.std(finite):.2g}×"
    return text + (f", {r.size - finite.size} diverged" if finite.size < r.size else "")


def reason(row: Row) -> str:
    """Why, from the run: what ``drop`` leaves, estimate's fallbacks, what coincides."""
    said = [
        f"the graph drop leaves was rigid in {row.rigid_share:.0%} of epochs and connected in "
        f"{row.connected_share:.0%}; {LAWS[row.controller]}"
    ]
    if row.fallbacks >= 1:
        said.append(
            f"estimate fell back to hold {row.fallbacks:.0f} times in a run's {row.epochs} epochs: "
            "no estimate reached the agent, or the leader could not observe the neighbour"
        )
    same = [" = ".join(g) for g in row.coinciding() if "estimate" in g or "drop" in g]
    if same:
        said.append(f"{'; '.join(same)} to the bit")
    return "; ".join(said)


def _line(row: Row) -> str:
    """A row in full: the three strategies' errors, the ratios, the seeds won and why."""
    e = row.errors
    wins = int(np.sum(e["estimate"] < e["drop"]))
    return (
        f"- **{row.controller}, {row.case}**: estimate {_m(e['estimate'])}; drop {_m(e['drop'])} "
        f"({_times(row.ratio('drop'))} estimate's), hold {_m(e['hold'])} "
        f"({_times(row.ratio('hold'))}); estimate beats drop in {wins} of {len(e['drop'])} seeds. "
        f"Why: {reason(row)}."
    )


def _short(row: Row) -> str:
    """A row in one line: the ratios and what drop left."""
    said = f"rigid {row.rigid_share:.0%}, connected {row.connected_share:.0%}"
    if row.fallbacks >= 1:
        said += f", {row.fallbacks:.0f} fallbacks to hold"
    return (
        f"- {row.controller}, {row.case}: drop/estimate {_times(row.ratio('drop'))}; "
        f"hold/estimate {_times(row.ratio('hold'))} ({said})"
    )


def in_short(by: dict[str, list[Row]], total: int) -> str:
    """The regions counted, and what the rows of each share, from the numbers."""
    lines = []
    pays, worse = by.get("pays", []), by.get("worse", [])
    if pays:
        laws = ", ".join(sorted({r.controller for r in pays}))
        lines.append(
            f"Estimate beats drop and hold by ≥ {PAYS:g}× in {len(pays)} of {total} rows, all "
            f"under {laws}; in each the graph drop leaves was rigid in at most "
            f"{max(r.rigid_share for r in pays):.0%} of epochs and connected in at least "
            f"{min(r.connected_share for r in pays):.0%}."
        )
    as_good = by.get("same", []) + worse
    if as_good:
        laws = ", ".join(f"{k} {sum(r.controller == k for r in as_good)}" for k in LAWS)
        lines.append(f"Drop is as good or better in {len(as_good)} rows ({laws}).")
    if worse:
        lines.append(
            f"Drop is better in {len(worse)}, each where estimate fell back to hold at least "
            f"{min(r.fallbacks for r in worse):.0f} times per run."
        )
    return " ".join(lines)


def regions_markdown(all_rows: list[Row]) -> str:
    """The opening of ``results.md``: the regions counted, then each row with its numbers;
    in full where estimate pays and where drop is better, in one line elsewhere."""
    by: dict[str, list[Row]] = {}
    for r in all_rows:
        by.setdefault(verdict(r), []).append(r)
    text = [in_short(by, len(all_rows)), ""]
    heads = (
        ("pays", f"## Where estimate beats drop and hold (both ≥ {PAYS:g}× its error)", _line),
        ("worse", "## Where drop is better", _line),
        ("modest", "## Where estimate is best, by less", _short),
        ("same", f"## Where drop is as good (within {SAME:g}×)", _short),
    )
    for key, head, line in heads:
        text += [head, ""]
        text += [line(r) for r in by.get(key, [])] or ["- none"]
        text.append("")
    return "\n".join(text)


def map_table(all_rows: list[Row], strategies: tuple[str, ...], controller: str) -> str:
    """One controller's map: each case's mean ± std per strategy, and what drop left."""
    header = ["slice", "case", "rigid", "connected", "fallbacks", *strategies, "verdict"]
    body = []
    for r in all_rows:
        if r.controller != controller:
            continue
        cells = [_m(r.errors[s]).replace(" m", "") for s in strategies]
        body.append(
            [
                r.axis,
                r.case,
                f"{r.rigid_share:.0%}",
                f"{r.connected_share:.0%}",
                f"{r.fallbacks:.1f}",
                *cells,
                verdict(r),
            ]
        )
    return table(header, body)


def results_markdown(
    frame: pd.DataFrame, spec: ValueSpec, figure: str, real: list[dict[str, Any]]
) -> str:
    """``results.md``: the regions first, then the figure, the design and every row."""
    all_rows = rows(frame, spec)
    seeds = spec.seeds
    lines = [
        "# When does estimation pay?",
        "",
        f"Each row: a controller and a case, {len(seeds)} seeds ({seeds[0]}–{seeds[-1]}), "
        f"{spec.epochs} epochs; errors are the judged final error, mean ± standard deviation over "
        "the seeds (the edge-length error under the distance law, which leaves the formation "
        "free to rotate; the shape error under displacement consensus). Ratios are per seed, "
        "a strategy's error over estimate's.",
        "",
        regions_markdown(all_rows),
        f"![estimate, drop and hold per case]({figure})",
        "",
        "## Design",
        "",
        f"The base case is the chapter's pentagon (`{spec.scenario.name}`, minimally rigid), "
        f"link {LOST[0]}–{LOST[1]} down in both directions from epoch 1, the reference on the "
        "chapter's line; every other row changes one thing (its slice). Gains: "
        + ", ".join(f"{k} {v:g}" for k, v in GAINS.items())
        + " (each under its stable bound, docs/model.md §3). Kept: judged final error < "
        f"{KEEP_M:g} m. *rigid*, *connected*: the share of epochs in which the graph of the "
        "links delivered both ways was rigid, connected. *fallbacks*: estimate's substitutions "
        "that fell back to hold, per run.",
        "",
    ]
    for controller in spec.controllers:
        lines += [
            f"## {controller}",
            "",
            map_table(all_rows, spec.strategies, controller).rstrip("\n"),
            "",
        ]
    if real:
        header = ["region", "controller", "case", "strategy", "seed", "max abs(Δx)", "recorded"]
        header.append("match")
        keys = ["region", "controller", "case", "strategy", "seed", "max_diff", "recorded_diff"]
        keys.append("match")
        lines += [
            "## Real-process runs (lockstep, recorded) against the simulator",
            "",
            table(header, ([x[k] for k in keys] for x in real)).rstrip("\n"),
            "",
        ]
    return "\n".join(lines)


__all__ = ["Row", "map_table", "reason", "regions_markdown", "results_markdown", "rows", "verdict"]
