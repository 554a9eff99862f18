"""``formation experiment capacity``: keeping the formation as the network's capacity shrinks (issue 29).

Two studies (docs/model.md §9), each on the chapter's team and on ``grid20``:

- **access point**: every link of the team crosses one access point (a ``medium`` of all
  links, as Wi-Fi in infrastructure mode), its rate ``ρ × c_ap``;
- **access point, states only**: the same access point and rates, crossed by the formation
  links alone (reports and estimates reach the leader another way): what the estimation
  traffic costs the states when it shares their medium;
- **radios**: each sender's radio (every agent's, and the leader's for the estimates) at
  ``ρ × c_radio``.

``c`` is the least rate at which each phase's packets fit the phase (states 0.20 of the
period, reports 0.40, estimates 0.25): for the access point, the whole team's; for the
radios, the busiest sender's (the leader's radio carries every estimate), with the nominal
sizes of ``formation.wire_size`` plus the overhead. So at ``ρ ≥ 1`` everything fits (though
a phase's backlog still spills into the next) and below it the heaviest phase does not; at
the access point of these teams the states are that phase. Every queue holds :data:`LIMIT_PACKETS` and drops the tail.
A seed keeps the formation when its final shape error is under the threshold; the critical
capacity of a strategy is the least ``ρ`` of the grid from which every larger one keeps it in
≥ 95 % of the seeds.

Runs on the batch simulator; one real-process run per strategy (the chapter's team, the
access point at ``ρ = 1``) checks it, recorded.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from formation.deadlines import PHASES
from formation.markdown import table
from formation.scenario import STRATEGIES, Scenario, StrategyName
from formation.wire_size import WireSizes
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
from testbed.sim.plan import BatchPlan

MULTIPLES = tuple(round(0.25 * i, 2) for i in range(1, 9))  # ρ: 0.25 … 2
AP, AP_STATES, RADIOS = "access point", "access point (states only)", "radios"
STUDIES = (AP, AP_STATES, RADIOS)
OVERHEAD_BYTES = 42  # [B] IPv4 + UDP + Ethernet framing per packet
LIMIT_PACKETS = 1000  # Linux's default txqueuelen: the rate, not the buffer, decides
THRESHOLD_M = 0.05
COLUMNS = (
    "study",
    "topology",
    "strategy",
    "rate_multiple",
    "rate_bps",
    "seed",
    "final_error_m",
    "kept",
    "formation_delivered",
    "report_delivered",
    "estimate_delivered",
)


@dataclass(frozen=True)
class CapacitySpec:
    topologies: tuple[tuple[str, Scenario], ...]
    multiples: tuple[float, ...] = MULTIPLES
    seeds: tuple[int, ...] = tuple(range(1, 21))
    strategies: tuple[StrategyName, ...] = STRATEGIES
    studies: tuple[str, ...] = STUDIES
    epochs: int = 50
    threshold_m: float = THRESHOLD_M


@dataclass(kw_only=True)
class CapacityResult(GridResult):
    """The grid's columns are ``"study, topology"`` labels; success, critical and median_error
    by (label, strategy)."""

    spec: CapacitySpec
    median_error: dict[tuple[str, str], np.ndarray]
    load: dict[str, dict[str, float]]  # topology → bytes per epoch by phase, and c_ap, c_radio


def epoch_load(s: Scenario) -> dict[str, float]:
    """One epoch's bytes by phase [B] (nominal, with the overhead) and the rates ``c`` [bit/s].

    ``c_ap``: the rate at which the access point fits each phase's packets of the whole team
    in that phase; ``c_radio``: the same for the busiest sender's radio (the leader's holds
    every estimate).
    """
    sizes = WireSizes(s)
    period = s.control.period_s
    agents = range(1, s.n + 1)
    state = {i: sizes.payload_bytes("state", i, s.epochs) + OVERHEAD_BYTES for i in agents}
    report = {i: sizes.payload_bytes("report", i, s.epochs) + OVERHEAD_BYTES for i in agents}
    estimate = {i: sizes.payload_bytes("estimate", i, s.epochs) + OVERHEAD_BYTES for i in agents}
    out_degree = dict.fromkeys(agents, 0)
    for a, _ in s.directed_links.tolist():
        out_degree[a] += 1
    window = {p: (end - start) * period for p, (start, end) in PHASES.items()}  # [s]
    load = {
        "states": float(sum(state[i] * out_degree[i] for i in agents)),
        "reports": float(sum(report.values())),
        "estimates": float(sum(estimate.values())),
    }
    load["c_ap"] = 8 * max(
        load["states"] / window["state"],
        load["reports"] / window["report"],
        load["estimates"] / window["estimate"],
    )
    agent_radio = max(
        max(state[i] * out_degree[i] / window["state"], report[i] / window["report"])
        for i in agents
    )
    load["c_radio"] = 8 * max(agent_radio, load["estimates"] / window["estimate"])
    return load


def capacity_variant(s: Scenario, study: str, multiple: float, epochs: int) -> Scenario:
    """``s`` with its access point (all links, or the formation's), or every radio, at
    ``multiple × c``; both access points at the same rates."""
    load = epoch_load(s)
    queue = {"limit_packets": LIMIT_PACKETS, "overhead_bytes": OVERHEAD_BYTES}
    if study in (AP, AP_STATES):
        rate = multiple * load["c_ap"]
        links = "all" if study == AP else "formation"
        caps = [{"scope": "medium", "medium": "ap", "links": links, "rate_bps": rate, **queue}]
    else:
        rate = multiple * load["c_radio"]
        caps = [
            {"scope": "radio", "agent": i, "rate_bps": rate, **queue} for i in range(0, s.n + 1)
        ]
    net = s.network.model_dump(by_alias=True)
    net["capacity"] = caps
    return s.with_overrides(network=net, epochs=epochs)


def judge(threshold_m: float) -> Callable[[BatchResult], dict[str, np.ndarray]]:
    """What a cell measures: its final shape error, kept or not, and the share of formation
    packets delivered."""

    def measure(res: BatchResult) -> dict[str, np.ndarray]:
        errors = np.asarray(res.shape_error[-1], dtype=float)
        return {
            "final_error_m": errors,
            "kept": errors < threshold_m,
            "formation_delivered": res.delivered.mean(axis=(0, 2)),
        }

    return measure


def control_delivered(plan: BatchPlan) -> dict[str, np.ndarray]:
    """The share of reports and of estimates delivered in time, per member of ``plan``."""
    n = plan.base.n
    return {
        "report_delivered": plan.report_ok.reshape(plan.epochs, -1, n).mean(axis=(0, 2)),
        "estimate_delivered": plan.estimate_ok.reshape(plan.epochs, -1, n).mean(axis=(0, 2)),
    }


def run_capacity(spec: CapacitySpec, log: Callable[[str], None] = print) -> CapacityResult:
    """Every study, topology, strategy, capacity and seed on the batch simulator."""
    frames = []
    for study in spec.studies:
        for name, scenario in spec.topologies:
            label = f"{study}, {name}"
            variants = []
            for m in spec.multiples:
                s = capacity_variant(scenario, study, m, spec.epochs)
                keys = {"label": label, "study": study, "topology": name, "rate_multiple": m}
                variants.append(Variant({**keys, "rate_bps": s.network.capacity[0].rate_bps}, s))
            log(f"capacity: {label}: planning {len(variants) * len(spec.seeds)} runs …")
            frames.append(
                run_grid(
                    variants,
                    spec.seeds,
                    spec.strategies,
                    judge(spec.threshold_m),
                    planned=control_delivered,
                    log=progress(log, f"capacity: {label}"),
                )
            )
    frame = pd.concat(frames, ignore_index=True)
    by, points = ("label", "strategy"), spec.multiples
    success = over_grid(frame, by, "rate_multiple", points, kept_fraction)
    median = over_grid(
        frame, by, "rate_multiple", points, lambda c: float(np.median(c["final_error_m"]))
    )
    return CapacityResult(
        spec=spec,
        frame=frame,
        strategies=spec.strategies,
        points=spec.multiples,
        columns=tuple(labels(spec)),
        success=success,
        critical={k: critical(points, v, easiest="high") for k, v in success.items()},
        median_error=median,
        load={name: epoch_load(s) for name, s in spec.topologies},
    )


def labels(spec: CapacitySpec) -> list[str]:
    return [f"{study}, {name}" for study in spec.studies for name, _ in spec.topologies]


def results_markdown(r: CapacityResult) -> str:
    spec = r.spec
    text = [
        "# Capacity: the formation against the network's capacity",
        "",
        " ".join(r.conclusion("capacity ρ", "high")),
        "",
        "![success against capacity](phase.png)",
        "",
        "*The fraction of seeds keeping the formation (colour) per strategy (rows) and capacity "
        "ρ (columns, a multiple of the least rate that fits each phase), one panel per case; "
        "the white bar is each strategy's critical capacity.*",
        "",
        "## How it was run",
        "",
        f"{spec.epochs} epochs, seeds {spec.seeds[0]}–{spec.seeds[-1]} ({len(spec.seeds)}), the "
        "batch simulator (netem's lockstep drops the same packets: "
        "`tests/integration/test_capacity_lockstep.py`). Capacity ρ is a multiple of `c`, the "
        "least rate at which each phase's packets fit their phase (states 0.20 of the period, "
        "reports 0.40, estimates 0.25): the access point carries every link (`c_ap`), a radio "
        "its sender's out-links (`c_radio`: the busiest radio's need, the leader's estimates "
        f"included). Queues of {LIMIT_PACKETS} packets, tail drop, "
        f"{OVERHEAD_BYTES} B of framing per packet; packet sizes nominal "
        "(`formation/wire_size.py`). Kept: final shape error < "
        f"{spec.threshold_m:g} m; critical capacity: the least ρ from which every larger one "
        f"keeps in ≥ {KEEP_FRACTION:.0%} of the seeds.",
        "",
        "## One epoch's traffic",
        "",
        load_markdown(r).rstrip("\n"),
    ]
    text += ["", "## Critical capacity per strategy", "", r.critical_markdown()]
    text += ["## What the numbers show", "", *what_it_shows(r), ""]
    text += ["## Fraction of seeds keeping the formation, and median final shape error [m]", ""]

    def cell(c: str, s: str, i: int) -> str:
        return f"{r.success[(c, s)][i]:.2f} ({r.median_error[(c, s)][i]:.3g})"

    for c in labels(spec):
        text += [f"### {c}", "", r.success_markdown(c, cell)]
    if r.real:
        header = ["strategy", "ρ", "seed", "max abs(Δx)", "recorded", "match", "recording"]
        rest = ("seed", "max_diff", "recorded_diff", "match", "recording")
        rows = ([x["strategy"], f"{x['rate_multiple']:g}", *(x[k] for k in rest)] for x in r.real)
        text += ["## Real-process runs (recorded)", "", table(header, rows).rstrip("\n")]
    return "\n".join([*text, ""])


def load_markdown(r: CapacityResult) -> str:
    """One epoch's bytes by phase per topology, the control traffic's share and the rates ``c``."""
    header = ["topology", "states [B]", "reports [B]", "estimates [B]", "control share"]
    rows = []
    for name, ld in r.load.items():
        total = ld["states"] + ld["reports"] + ld["estimates"]
        share = (ld["reports"] + ld["estimates"]) / total
        rows.append(
            [
                name,
                f"{ld['states']:.0f}",
                f"{ld['reports']:.0f}",
                f"{ld['estimates']:.0f}",
                f"{share:.0%}",
                f"{ld['c_ap'] / 1e3:.1f}",
                f"{ld['c_radio'] / 1e3:.1f}",
            ]
        )
    return table([*header, "c_ap [kbit/s]", "c_radio [kbit/s]"], rows)


def what_it_shows(r: CapacityResult) -> list[str]:
    """Plain sentences on the numbers: who keeps the formation at the least capacity."""
    out = []
    for c in labels(r.spec):
        crit = {s: r.critical[(c, s)] for s in r.spec.strategies}
        known = {s: v for s, v in crit.items() if v is not None}
        if not known:
            out.append(f"- {c}: no strategy keeps the formation even at the largest capacity.")
            continue
        least = min(known.values())
        best = ", ".join(s for s, v in known.items() if v == least)
        never = ", ".join(s for s, v in crit.items() if v is None)
        out.append(
            f"- {c}: {best} keep{'s' if ',' not in best else ''} the formation down to ρ = "
            f"{least:g}"
            + (f"; {never} not even at ρ = {r.spec.multiples[-1]:g}" if never else "")
            + "."
        )
    out += estimation_cost(r)
    return out


def estimation_cost(r: CapacityResult) -> list[str]:
    """What the reports and estimates cost at the access point: each strategy with them on
    the medium against without (the same rates), and whether ``estimate`` pays for them."""
    if not {AP, AP_STATES} <= set(r.spec.studies):
        return []
    out = [
        "- Every strategy sends the same traffic (agents report, the leader estimates, whatever "
        "the strategy: the control share above). Taking the reports and estimates off the "
        "access point (same rates) shows what that traffic costs:"
    ]

    def crit(study: str, name: str, strategy: str) -> str:
        c = r.critical[(f"{study}, {name}", strategy)]
        return "never" if c is None else f"ρ = {c:g}"

    for name, _ in r.spec.topologies:
        moved = [f"{s} {crit(AP, name, s)} → {crit(AP_STATES, name, s)}" for s in r.spec.strategies]
        out.append(f"  - {name}, critical capacity with → without: " + "; ".join(moved) + ".")
        if {"estimate", "hold"} <= set(r.spec.strategies):
            paid = r.critical[(f"{AP}, {name}", "estimate")]
            free = r.critical[(f"{AP_STATES}, {name}", "hold")]
            if paid is not None and (free is None or paid < free):
                verdict = "pays for its traffic: it keeps the formation at less capacity"
            elif paid is not None and paid == free:
                verdict = "breaks even: both keep the formation from the same capacity"
            else:
                verdict = "does not pay for its traffic here"
            out.append(
                f"  - {name}: `estimate` carrying its reports and estimates ({crit(AP, name, 'estimate')}) "
                f"against `hold` spared them ({crit(AP_STATES, name, 'hold')}): estimation {verdict}."
            )
    return out


def run_capacity_real(
    r: CapacityResult,
    out: Path,
    multiple: float = 1.0,
    record: bool = True,
    log: Callable[[str], None] = print,
) -> None:
    """One real-process run per strategy: the first topology, the access point at ``multiple``."""
    spec = r.spec
    name, base = spec.topologies[0]
    scenario = capacity_variant(base, AP, multiple, spec.epochs)
    for s in spec.strategies:
        seed = spec.seeds[0]
        log(f"capacity, real processes: {name}, {s}, seed {seed} …")
        row: dict[str, Any] = {
            "strategy": s,
            "rate_multiple": multiple,
            "seed": seed,
        }
        r.real.append(real_run_row(scenario, s, seed, out / "runs", record, row))


def write_outputs(r: CapacityResult, out: Path) -> None:
    """``runs.csv``, ``critical.md``, ``results.md`` and ``phase.png`` in ``out``."""
    title = "Critical capacity per strategy (ρ: multiples of the rate the states need)"
    xlabel = "capacity ρ (× the rate one epoch's states need)"
    results, columns = results_markdown(r), len(r.spec.topologies)
    write_grid_outputs(
        r, out, COLUMNS, title, results, r.spec.threshold_m, xlabel=xlabel, columns=columns
    )


__all__ = [
    "COLUMNS",
    "MULTIPLES",
    "STUDIES",
    "CapacityResult",
    "CapacitySpec",
    "capacity_variant",
    "control_delivered",
    "epoch_load",
    "judge",
    "run_capacity",
    "run_capacity_real",
    "write_outputs",
]
