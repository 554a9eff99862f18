"""``formation experiment wireless --contention``: keeping the formation as more agents share the air.

Teams of each size (``rigid_team``, agents about ``spacing_m`` apart, the access point at
their centre) put every link on one 802.11 channel (docs/model.md §11) at each PHY rate,
with the reports and estimates on the same channel (``shared``) or off it (``own``: the
leader's traffic on a channel of its own, lossless here). No link model drops a packet:
every loss is the air's, by contention, collisions and hidden terminals. A seed keeps the
formation when its final shape error is under the threshold; the critical team size of a
strategy is the largest of the grid up to which every size keeps the formation in ≥ 95 %
of the seeds. Does the estimation traffic cost ``estimate`` its advantage, and from how
many agents?

Runs on the batch simulator (:func:`testbed.experiments.grid.run_grid`, one plan per team).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

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

SIZES = (5, 10, 20)
RATES_MBPS = (6.0, 24.0)
CHANNELS = ("shared", "own")
SPACING_M = 15.0
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
    """A team of ``n`` on one channel at ``rate_mbps``; its control links on it (shared) or not."""
    team = rigid_team(n, 2, 0.0, spec.spacing_m, seed=1, epochs=spec.epochs)
    air = {"links": "all" if channel == "shared" else "formation", "rate_mbps": rate_mbps}
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
    """Every case, team size, strategy and seed on the batch simulator."""
    frames = []
    labels = []
    for rate in spec.rates_mbps:
        for channel in spec.channels:
            label = case_label(rate, channel)
            labels.append(label)
            for n in spec.sizes:
                variant = Variant(
                    {"case": label, "agents": n}, contention_variant(spec, n, rate, channel)
                )
                frames.append(
                    run_grid(
                        [variant],
                        spec.seeds,
                        spec.strategies,
                        judge(spec.threshold_m),
                        log=progress(log, f"contention: {label}, {n} agents"),
                    )
                )
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


def contention_results_markdown(r: ContentionResult) -> str:
    spec = r.spec
    cells = r.frame.groupby(["case", "agents"], sort=False)
    delivered = table(
        ["case", "agents", "states delivered", "reports delivered"],
        (
            [
                case,
                f"{n:g}",
                *(f"{g[c].mean():.3f}" for c in ("formation_delivered", "reports_delivered")),
            ]
            for (case, n), g in cells
        ),
    )
    text = [
        "# Contention: the formation as more agents share the air",
        "",
        f"Teams of {', '.join(str(n) for n in spec.sizes)} agents about {spec.spacing_m:g} m "
        "apart on one 802.11 channel (docs/model.md §11), every loss the air's; reports and "
        "estimates on it (shared) or off it (own). A seed keeps the formation when its final "
        f"shape error is under {spec.threshold_m:g} m; {len(spec.seeds)} seeds, "
        f"{spec.epochs} epochs.",
        "",
        "## Critical team size (the largest that keeps, from the smallest up)",
        "",
        r.critical_markdown().rstrip("\n"),
        "",
        "## What the air delivered (mean over strategies and seeds)",
        "",
        delivered.rstrip("\n"),
    ]
    for label in r.columns:
        text += ["", f"## Kept fraction, {label}", "", r.kept_markdown(label).rstrip("\n")]
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
    )


__all__ = [
    "CHANNELS",
    "COLUMNS",
    "RATES_MBPS",
    "SIZES",
    "ContentionResult",
    "ContentionSpec",
    "contention_variant",
    "run_contention",
    "write_outputs",
]
