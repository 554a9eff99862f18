"""``formation experiment wireless --contention``: keeping the formation as more agents share the air.

Teams of each size (``rigid_team``, agents about ``spacing_m`` apart, the access point at
their centre) broadcast their states on one 802.11 channel (docs/model.md §11) at each PHY
rate. The estimation traffic (reports, estimates) goes in one of three ways:

- ``shared``: on the states' channel, each report in the states' contention period
  (``network.air.reports = "with_states"``), the estimates after;
- ``own``: the same timing on a second channel of its own (``control_channel = "own"``);
- ``off``: off the air, lossless (``links = "formation"``).

A strategy that never reads the estimates (``zero``, ``hold``, ``drop``) sends no
estimation traffic on the air in any case (``estimation_traffic = "when_used"``): its runs
are the same in every case, run once (``off``) and shown in each. No link model drops a
packet: every loss is the air's, by contention, collisions and hidden terminals. A seed
keeps the formation when its final shape error is under the threshold; the critical team
size of a strategy is the largest of the grid up to which every size keeps the formation in
≥ 95 % of the seeds. Does the estimation traffic cost ``estimate`` its advantage, and from
how many agents? :func:`answer` says, first in ``results.md``.

Runs on the batch simulator (:func:`testbed.experiments.grid.run_grid`, one plan per team).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from formation.air import WITHOUT_ESTIMATES
from formation.markdown import table
from formation.scenario import STRATEGIES, Scenario, StrategyName
from testbed.experiments.grid import (
    GridResult,
    Variant,
    critical,
    kept_fraction,
    over_grid,
    progress,
    run_grid,
)
from testbed.experiments.grid import write_outputs as write_grid_outputs
from testbed.sim.batch import BatchResult
from testbed.sim.team_generators import rigid_team

SIZES = (5, 10, 15, 20)
RATES_MBPS = (6.0, 24.0)
CHANNELS = ("shared", "own", "off")
OFF = "off"
CHANNEL_WORDS = {
    "shared": "on the states' channel",
    "own": "on a channel of its own",
    "off": "off the air",
}
SPACING_M = 15.0
MARGIN = 0.05  # a ratio of median errors this far above 1 counts as worse (the seeds' spread)
THRESHOLD_M = 0.05
COLUMNS = (
    "case",
    "strategy",
    "agents",
    "seed",
    "final_error_m",
    "kept",
    "formation_delivered",
    "reports_delivered",
)


@dataclass(frozen=True)
class ContentionSpec:
    sizes: tuple[int, ...] = SIZES
    rates_mbps: tuple[float, ...] = RATES_MBPS
    channels: tuple[str, ...] = CHANNELS
    seeds: tuple[int, ...] = tuple(range(1, 11))
    strategies: tuple[StrategyName, ...] = STRATEGIES
    epochs: int = 150  # a 20-agent team needs about that to settle under 0.05 m, lossless
    spacing_m: float = SPACING_M
    threshold_m: float = THRESHOLD_M


@dataclass(kw_only=True)
class ContentionResult(GridResult):
    """Columns are the cases (``"6 Mb/s, shared"``); points the team sizes."""

    spec: ContentionSpec

    def critical_markdown(self) -> str:
        """The critical team size per strategy (rows) and case (columns)."""

        def size(c: str, s: str) -> str:
            got = self.critical[(c, s)]
            return "none" if got is None else f"{got:g}"

        return table(
            ["strategy", *self.columns],
            ([s, *(size(c, s) for c in self.columns)] for s in self.strategies),
        )

    def kept_markdown(self, label: str) -> str:
        """Per team size (rows) and strategy: the fraction of seeds that kept the formation."""
        rows = (
            [f"{p:g}", *(f"{self.success[(label, s)][i]:.2f}" for s in self.strategies)]
            for i, p in enumerate(self.points)
        )
        return table(["agents", *self.strategies], rows)


def case_label(rate_mbps: float, channel: str) -> str:
    return f"{rate_mbps:g} Mb/s, {channel}"


def contention_variant(spec: ContentionSpec, n: int, rate_mbps: float, channel: str) -> Scenario:
    """A team of ``n`` on one channel at ``rate_mbps``, its estimation traffic as ``channel``
    says (module docstring)."""
    team = rigid_team(n, 2, 0.0, spec.spacing_m, seed=1, epochs=spec.epochs)
    air: dict[str, object] = {"links": "formation", "rate_mbps": rate_mbps}
    if channel != OFF:
        air |= {
            "links": "all",
            "reports": "with_states",
            "control_channel": channel,
            "estimation_traffic": "when_used",
        }
    network = {"access_point": team.offsets.mean(axis=0).tolist(), "air": air}
    return team.with_overrides(network=network, name=f"contention{n}")


def judge(threshold_m: float) -> Callable[[BatchResult], dict[str, np.ndarray]]:
    """A cell's final shape error, kept or not, and the share of states and reports delivered."""

    def measure(res: BatchResult) -> dict[str, np.ndarray]:
        errors = np.asarray(res.shape_error[-1], dtype=float)
        reports = res.report_ok if res.report_ok is not None else res.plan.report_ok
        return {
            "final_error_m": errors,
            "kept": errors < threshold_m,
            "formation_delivered": res.delivered.mean(axis=(0, 2)),
            "reports_delivered": reports.mean(axis=(0, 2)),
        }

    return measure


def run_contention(spec: ContentionSpec, log: Callable[[str], None] = print) -> ContentionResult:
    """Every case, team size, strategy and seed on the batch simulator; a strategy without
    estimates once per rate and size (its runs are the same in every case)."""
    frames = []
    labels = []
    channels = sorted(spec.channels, key=lambda c: c != OFF)  # off first: the others copy it
    without = [s for s in spec.strategies if s in WITHOUT_ESTIMATES]
    for rate in spec.rates_mbps:
        labels += [case_label(rate, c) for c in spec.channels]
        for n in spec.sizes:
            alone: pd.DataFrame | None = None  # the runs without estimates, this rate and size
            for channel in channels:
                label = case_label(rate, channel)
                todo = (
                    spec.strategies
                    if alone is None
                    else tuple(s for s in spec.strategies if s not in WITHOUT_ESTIMATES)
                )
                variant = Variant(
                    {"case": label, "agents": n}, contention_variant(spec, n, rate, channel)
                )
                got = run_grid(
                    [variant],
                    spec.seeds,
                    todo,
                    judge(spec.threshold_m),
                    log=progress(log, f"contention: {label}, {n} agents"),
                )
                if alone is not None and not alone.empty:
                    got = pd.concat([alone.assign(case=label), got], ignore_index=True)
                elif without:
                    alone = got[got["strategy"].isin(without)]
                if channel in spec.channels:
                    frames.append(got)
    frame = pd.concat(frames, ignore_index=True)
    sizes = tuple(float(n) for n in spec.sizes)
    frame["agents"] = frame["agents"].astype(float)
    success = over_grid(frame, ("case", "strategy"), "agents", sizes, kept_fraction)
    return ContentionResult(
        spec=spec,
        frame=frame,
        strategies=spec.strategies,
        points=sizes,
        columns=tuple(labels),
        success=success,
        critical={k: critical(sizes, v, easiest="low") for k, v in success.items()},
    )


def median_errors(r: ContentionResult, case: str, strategy: str) -> np.ndarray:
    """(R,) the median final shape error [m] over the seeds at each team size."""
    cells = r.frame[(r.frame["case"] == case) & (r.frame["strategy"] == strategy)]
    at = cells.groupby("agents")["final_error_m"].median()
    return np.array([at.get(p, np.nan) for p in r.points])


def answer(r: ContentionResult, strategy: StrategyName = "estimate") -> str:
    """Whether the estimation traffic costs ``strategy`` its advantage, and from how many
    agents: its median final error over the best strategy without estimates' (which send none
    on the air) at each team size in each case; the traffic costs it where that ratio is over
    ``1 + MARGIN`` and over ``1 + MARGIN`` times the ratio with the traffic off the air (a
    margin for the seeds' spread); and where each keeps the formation."""
    spec = r.spec
    base = [s for s in r.strategies if s in WITHOUT_ESTIMATES]
    if strategy not in r.strategies or not base or OFF not in spec.channels:
        return f"(`{strategy}`, a strategy without estimates and the case off are needed)"
    sizes = "/".join(f"{p:g}" for p in r.points)
    verdicts, ratios = [], []
    for rate in spec.rates_mbps:
        off = case_label(rate, OFF)
        floor = np.min([median_errors(r, off, s) for s in base], axis=0)
        ratio = {c: median_errors(r, case_label(rate, c), strategy) / floor for c in spec.channels}
        shown = ", ".join(
            f"{'/'.join(f'{v:.2f}' for v in ratio[c])} {CHANNEL_WORDS[c]}" for c in spec.channels
        )
        ratios.append(f"at {rate:g} Mb/s {shown}")
        for c in (c for c in spec.channels if c != OFF):
            cost = (ratio[c] > 1 + MARGIN) & (ratio[c] > (1 + MARGIN) * ratio[OFF])
            kept = r.critical[(case_label(rate, c), strategy)]
            theirs = max(r.critical[(off, s)] or 0.0 for s in base) or None
            where = _sizes_where(r.points, cost)
            verdicts.append(
                f"{CHANNEL_WORDS[c]} at {rate:g} Mb/s {where} (kept up to "
                f"{'no size' if kept is None else f'{kept:g}'} agents; they: "
                f"{'no size' if theirs is None else f'{theirs:g}'})"
            )
    costs = [v for v in verdicts if " at no size " not in v]
    return (
        f"**Does the estimation traffic cost `{strategy}` its advantage?** "
        + ("Yes, " if costs else "No; ")
        + "with the traffic "
        + "; ".join(verdicts)
        + f". Its median final error ÷ the best of {', '.join(f'`{s}`' for s in base)} "
        + f"(no estimates, none of their traffic) at {sizes} agents: "
        + "; ".join(ratios)
        + f" ({len(spec.seeds)} seeds, {spec.epochs} epochs; kept: final shape error under "
        + f"{spec.threshold_m:g} m in ≥ 95 % of the seeds)."
    )


def _sizes_where(points: Sequence[float] | np.ndarray, cost: np.ndarray) -> str:
    """The team sizes where ``cost`` holds, in words: "from 10 agents" when it holds at every
    size from there up, else each size named (a cost that comes and goes is not a threshold)."""
    points, cost = np.asarray(points), np.asarray(cost, dtype=bool)
    if not cost.any():
        return "at no size"
    first = int(np.argmax(cost))
    if cost[first:].all():
        return f"from {points[first]:g} agents"
    return "at " + ", ".join(f"{p:g}" for p in points[cost]) + " agents only"


def contention_results_markdown(r: ContentionResult) -> str:
    spec = r.spec
    users = r.frame[~r.frame["strategy"].isin(WITHOUT_ESTIMATES)]  # their traffic on the air
    delivered = table(
        ["case", "agents", "states delivered", "reports delivered"],
        (
            [
                case,
                f"{n:g}",
                *(f"{g[c].mean():.3f}" for c in ("formation_delivered", "reports_delivered")),
            ]
            for (case, n), g in users.groupby(["case", "agents"], sort=False)
        ),
    )
    ways = "; ".join(f"{c}: {CHANNEL_WORDS[c]}" for c in spec.channels)
    text = [
        answer(r),
        "",
        "# Contention: the formation as more agents share the air",
        "",
        f"Teams of {', '.join(str(n) for n in spec.sizes)} agents about {spec.spacing_m:g} m "
        "apart broadcast their states on one 802.11 channel (docs/model.md §11), every loss "
        "the air's. The estimation traffic of the strategies that use it (reports in the "
        f"states' contention period, estimates after) goes {ways}. `zero`, `hold` and `drop` "
        "never read the estimates and send none on the air (`estimation_traffic = "
        '"when_used"`): their runs are the same in every case. A seed keeps the formation '
        f"when its final shape error is under {spec.threshold_m:g} m; seeds "
        f"{', '.join(str(s) for s in spec.seeds)}, {spec.epochs} epochs.",
        "",
        "## Critical team size (the largest that keeps, from the smallest up)",
        "",
        r.critical_markdown().rstrip("\n"),
        "",
        "## What the air delivered to the strategies that use the estimates (mean over seeds)",
        "",
        delivered.rstrip("\n"),
    ]
    for label in r.columns:
        text += ["", f"## Kept fraction, {label}", "", r.kept_markdown(label).rstrip("\n")]
    for label in r.columns:
        errors = table(
            ["agents", *r.strategies],
            (
                [f"{p:g}", *(f"{median_errors(r, label, s)[i]:.4g}" for s in r.strategies)]
                for i, p in enumerate(r.points)
            ),
        )
        text += ["", f"## Median final shape error [m], {label}", "", errors.rstrip("\n")]
    return "\n".join([*text, ""])


def write_outputs(r: ContentionResult, out: Path) -> None:
    """``runs.csv``, ``critical.md``, ``results.md`` and ``phase.png`` in ``out``."""
    results = contention_results_markdown(r)
    write_grid_outputs(
        r,
        out,
        COLUMNS,
        "Critical team size per strategy on a shared channel",
        results,
        r.spec.threshold_m,
        xlabel="agents on the channel",
        columns=len(r.spec.channels),
        easiest="low",
        reference=None,
    )


__all__ = [
    "CHANNELS",
    "CHANNEL_WORDS",
    "COLUMNS",
    "RATES_MBPS",
    "SIZES",
    "ContentionResult",
    "ContentionSpec",
    "answer",
    "contention_variant",
    "median_errors",
    "run_contention",
    "write_outputs",
]
