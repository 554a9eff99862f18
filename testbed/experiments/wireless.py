"""``formation experiment wireless``: keeping the formation as the radio range shrinks (issue 19).

Every formation link gets the ``logistic`` distance model, its ``d50_m`` (the radio range,
where half the packets arrive) a multiple ``ρ`` of the formation's longest edge and its
``width_m`` a fixed fraction of that edge; the control links stay as the scenario has them
(infrastructure: they reach the leader at any distance). Two controllers: the displacement
law with single integrators, and the distance law with unicycles (docs/model.md §3). A seed
keeps the formation when its final error is under the threshold: the shape error for the
displacement law, the edge-length error (``formation_error``) for the distance law, which
controls lengths only and leaves the formation free to rotate. The critical range of a
strategy is the least ``ρ`` of the grid from which every larger one keeps the formation in
≥ 95 % of the seeds. Below ``ρ = 1`` the longest formation links are mostly out of range
while the leader is still reached: which strategies keep the formation there is the
question the chapter does not ask.

Runs on the batch simulator (:func:`testbed.sim.batch.run_batch`, every range and seed of a
controller in one batch); one real-process run per strategy checks it, recorded.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from formation.markdown import table
from formation.scenario import STRATEGIES, Scenario, StrategyName
from testbed.experiments.grid import (
    KEEP_FRACTION,
    GridResult,
    Variant,
    critical,
    kept_fraction,
    over_grid,
    progress,
    run_grid,
)
from testbed.experiments.grid import write_outputs as write_grid_outputs
from testbed.experiments.real_check import real_run_row
from testbed.sim.batch import BatchResult

RANGES = tuple(round(0.5 + 0.25 * i, 2) for i in range(11))  # ρ: 0.5 … 3 × the longest edge
WIDTH_FRACTION = 0.1  # logistic width_m / longest edge
THRESHOLD_M = 0.05


@dataclass(frozen=True)
class Case:
    """A controller and the robots it drives; ``gain`` None keeps the scenario's."""

    controller: str
    dynamics: str
    gain: float | None = None

    @property
    def label(self) -> str:
        return f"{self.controller}, {self.dynamics}"


# The distance law's step grows with C²: the scenario's gain (0.25) diverges on the pentagon
# (C up to 1.9 m) and 0.05 is the largest of 0.02, 0.05, 0.1 that converges for every seed.
CASES = (Case("displacement", "single"), Case("distance", "unicycle", 0.05))
COLUMNS = (
    "case",
    "strategy",
    "range_multiple",
    "d50_m",
    "seed",
    "final_error_m",
    "kept",
    "formation_delivered",
    "saturated_steps",
)


@dataclass(frozen=True)
class WirelessSpec:
    scenario: Scenario
    ranges: tuple[float, ...] = RANGES
    seeds: tuple[int, ...] = tuple(range(1, 21))
    strategies: tuple[StrategyName, ...] = STRATEGIES
    cases: tuple[Case, ...] = CASES
    epochs: int = 100
    threshold_m: float = THRESHOLD_M
    width_fraction: float = WIDTH_FRACTION


@dataclass(kw_only=True)
class WirelessResult(GridResult):
    """The grid's columns are the cases' labels; success, critical by (case label, strategy)."""

    spec: WirelessSpec


def longest_edge(scenario: Scenario) -> float:
    """The formation's longest edge ``max C_ij`` [m]."""
    return float(np.max(scenario.weights))


def wireless_variant(spec: WirelessSpec, case: Case, multiple: float) -> Scenario:
    """The scenario with every formation link ``logistic`` at ``d50 = multiple × longest edge``."""
    s, edge = spec.scenario, longest_edge(spec.scenario)
    net = s.network.model_dump(by_alias=True)
    logistic = {
        "model": "logistic",
        "d50_m": multiple * edge,
        "width_m": spec.width_fraction * edge,
    }
    net.update(formation_default=[logistic], links=[])
    control = s.control.model_dump()  # the scenario's period, gain, limits ... kept
    control.update(controller=case.controller, dynamics=case.dynamics)
    if case.gain is not None:
        control["gain"] = case.gain
    return s.with_overrides(network=net, control=control, epochs=spec.epochs)


def final_judged_errors(case: Case, res: BatchResult) -> np.ndarray:
    """(B,) the final error that decides whether a member kept the formation [m]."""
    err = res.formation_error if case.controller == "distance" else res.shape_error
    return np.asarray(err[-1], dtype=float)


def judge(case: Case, threshold_m: float) -> Callable[[BatchResult], dict[str, np.ndarray]]:
    """What a cell of ``case`` measures: its judged final error, kept or not, the share of
    formation packets delivered and the unicycles' saturated steps."""

    def measure(res: BatchResult) -> dict[str, np.ndarray]:
        errors = final_judged_errors(case, res)
        saturated = (
            np.zeros(res.size, dtype=np.int64)
            if res.saturated is None
            else res.saturated.sum(axis=(0, 2))
        )
        return {
            "final_error_m": errors,
            "kept": errors < threshold_m,
            "formation_delivered": res.delivered.mean(axis=(0, 2)),
            "saturated_steps": saturated,
        }

    return measure


def run_wireless(spec: WirelessSpec, log: Callable[[str], None] = print) -> WirelessResult:
    """Every case, strategy, range and seed on the batch simulator."""
    frames = []
    for case in spec.cases:
        variants = []
        for rho in spec.ranges:
            s = wireless_variant(spec, case, rho)
            d50 = s.network.formation_default[0].d50_m  # type: ignore[attr-defined]
            variants.append(Variant({"case": case.label, "range_multiple": rho, "d50_m": d50}, s))
        frames.append(
            run_grid(
                variants,
                spec.seeds,
                spec.strategies,
                judge(case, spec.threshold_m),
                log=progress(log, f"wireless: {case.label}"),
            )
        )
    frame = pd.concat(frames, ignore_index=True)
    success = over_grid(frame, ("case", "strategy"), "range_multiple", spec.ranges, kept_fraction)
    return WirelessResult(
        spec=spec,
        frame=frame,
        strategies=spec.strategies,
        points=spec.ranges,
        columns=tuple(c.label for c in spec.cases),
        success=success,
        critical={k: critical(spec.ranges, v, easiest="high") for k, v in success.items()},
    )


def keep_out_of_range(r: WirelessResult, case: Case) -> dict[str, list[float]]:
    """Strategies that keep the formation at some ``ρ < 1`` (formation links out of range,
    the leader reached), with those ``ρ``."""
    out: dict[str, list[float]] = {}
    for s in r.spec.strategies:
        frac = r.success[(case.label, s)]
        below = [
            rho
            for rho, f in zip(r.spec.ranges, frac, strict=True)
            if rho < 1 and f >= KEEP_FRACTION
        ]
        if below:
            out[s] = below
    return out


def wireless_results_markdown(r: WirelessResult) -> str:
    spec = r.spec
    edge = longest_edge(spec.scenario)
    text = [
        "# Wireless: the formation against radio range",
        "",
        " ".join(r.conclusion("radio range ρ", "high")),
        "",
        "![success against range](phase.png)",
        "",
        "*The fraction of seeds keeping the formation (colour) per strategy (rows) and radio "
        "range ρ (columns, a multiple of the longest edge), one panel per case; the white bar "
        "is each strategy's critical range.*",
        "",
        "## How it was run",
        "",
        f"Scenario `{spec.scenario.name}` (n = {spec.scenario.n}, initial spread "
        f"{spec.scenario.initial.spread_m:g} m), {spec.epochs} epochs, seeds "
        f"{spec.seeds[0]}–{spec.seeds[-1]} ({len(spec.seeds)}). Every formation link `logistic`, "
        f"d50 = ρ × the longest edge ({edge:.4g} m), width {spec.width_fraction:g} × that edge; "
        "control links as the scenario has them (they reach the leader). Kept: final error < "
        f"{spec.threshold_m:g} m (shape error for the displacement law, edge-length error for "
        f"the distance law); critical range: the least ρ from which every larger one keeps in "
        f"≥ {KEEP_FRACTION:.0%} of the seeds.",
        "",
        "## Critical range per strategy",
        "",
        r.critical_markdown(),
        "## Formation links out of range, the leader reached (ρ < 1)",
        "",
    ]
    below = [i for i, rho in enumerate(spec.ranges) if rho < 1]
    for c in spec.cases:
        kept = keep_out_of_range(r, c)
        said = "; ".join(
            f"{s} (ρ = {', '.join(f'{v:g}' for v in rhos)})" for s, rhos in kept.items()
        )
        best = sorted(
            (
                (float(r.success[(c.label, s)][i]), -spec.ranges[i], s)
                for s in spec.strategies
                for i in below
            ),
            reverse=True,
        )[:3]
        most = ", ".join(f"{s} {f:.2f} at ρ = {-rho:g}" for f, rho, s in best)
        text.append(
            f"- {c.label}: {said or f'no strategy keeps it in ≥ {KEEP_FRACTION:.0%} of the seeds'}"
            + (f"; most kept: {most}" if best else "")
        )
    text += ["", "## Fraction of seeds keeping the formation"]
    for label in r.columns:
        text += ["", f"### {label}", "", r.success_markdown(label).rstrip("\n")]
    text.append("")
    if r.real:
        header = ["case", "strategy", "ρ", "seed", "max abs(Δx)", "recorded", "match", "recording"]
        rest = ("seed", "max_diff", "recorded_diff", "match", "recording")
        rows = (
            [x["case"], x["strategy"], f"{x['range_multiple']:g}", *(x[k] for k in rest)]
            for x in r.real
        )
        text += ["## Real-process runs (recorded)", "", table(header, rows).rstrip("\n")]
    return "\n".join([*text, ""])


def run_wireless_real(
    r: WirelessResult,
    out: Path,
    multiple: float = 1.0,
    record: bool = True,
    log: Callable[[str], None] = print,
) -> None:
    """One real-process run per strategy and case at ``ρ = multiple``, the median seed's."""
    spec = r.spec
    for case in spec.cases:
        scenario = wireless_variant(spec, case, multiple)
        for s in spec.strategies:
            errs = {
                row["seed"]: row["final_error_m"]
                for row in r.rows
                if row["case"] == case.label
                and row["strategy"] == s
                and row["range_multiple"] == multiple
            }
            median = float(np.median(list(errs.values())))
            seed = min(errs, key=lambda k: (abs(errs[k] - median), k))
            log(f"wireless, real processes: {case.label}, {s}, seed {seed} …")
            row: dict[str, Any] = {
                "case": case.label,
                "strategy": s,
                "range_multiple": multiple,
                "seed": seed,
            }
            r.real.append(real_run_row(scenario, s, seed, out / "runs", record, row))


def write_outputs(r: WirelessResult, out: Path) -> None:
    """``runs.csv``, ``critical.md``, ``results.md`` and ``phase.png`` in ``out``."""
    title = "Critical radio range per strategy"
    results = wireless_results_markdown(r)
    write_grid_outputs(r, out, COLUMNS, title, results, r.spec.threshold_m)


__all__ = [
    "CASES",
    "COLUMNS",
    "RANGES",
    "Case",
    "WirelessResult",
    "WirelessSpec",
    "judge",
    "keep_out_of_range",
    "longest_edge",
    "run_wireless",
    "run_wireless_real",
    "wireless_variant",
    "write_outputs",
]
