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

import csv
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from formation.deadlines import PHASES
from formation.scenario import STRATEGIES, Scenario, StrategyName
from formation.wire_size import WireSizes
from testbed.experiments.plots import plot_range_phase
from testbed.experiments.real_check import real_run_row
from testbed.experiments.studies import KEEP_FRACTION
from testbed.experiments.wireless import critical_range
from testbed.sim.batch import plan_batch, run_batch

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


@dataclass
class CapacityResult:
    """success, critical : (study, topology) label and strategy → (R,) kept / critical ``ρ``."""

    spec: CapacitySpec
    rows: list[dict[str, Any]]
    success: dict[tuple[str, str], np.ndarray]
    critical: dict[tuple[str, str], float | None]
    median_error: dict[tuple[str, str], np.ndarray]
    load: dict[str, dict[str, float]]  # topology → bytes per epoch by phase, and c_ap, c_radio
    real: list[dict[str, Any]] = field(default_factory=list)


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


def run_capacity(spec: CapacitySpec, log: Callable[[str], None] = print) -> CapacityResult:
    """Every study, topology, strategy, capacity and seed on the batch simulator."""
    rows: list[dict[str, Any]] = []
    success: dict[tuple[str, str], np.ndarray] = {}
    critical: dict[tuple[str, str], float | None] = {}
    median: dict[tuple[str, str], np.ndarray] = {}
    n_r, n_s = len(spec.multiples), len(spec.seeds)
    for study in spec.studies:
        for name, scenario in spec.topologies:
            label = f"{study}, {name}"
            variants = [capacity_variant(scenario, study, m, spec.epochs) for m in spec.multiples]
            members = [v for v in variants for _ in spec.seeds]
            log(f"capacity: {label}: planning {len(members)} runs …")
            plan = plan_batch(members, [seed for _ in variants for seed in spec.seeds])
            n = scenario.n
            for strategy in spec.strategies:
                log(f"capacity: {label}, {strategy} …")
                res = run_batch(plan, strategy, detail=False)
                errors = np.asarray(res.shape_error[-1], dtype=float).reshape(n_r, n_s)
                kept = errors < spec.threshold_m
                shares = [
                    res.delivered.mean(axis=(0, 2)),
                    plan.report_ok.reshape(plan.epochs, -1, n).mean(axis=(0, 2)),
                    plan.estimate_ok.reshape(plan.epochs, -1, n).mean(axis=(0, 2)),
                ]
                shares = [a.reshape(n_r, n_s) for a in shares]
                for i, m in enumerate(spec.multiples):
                    rate = variants[i].network.capacity[0].rate_bps
                    for j, seed in enumerate(spec.seeds):
                        rows.append(
                            {
                                "study": study,
                                "topology": name,
                                "strategy": strategy,
                                "rate_multiple": m,
                                "rate_bps": rate,
                                "seed": seed,
                                "final_error_m": float(errors[i, j]),
                                "kept": bool(kept[i, j]),
                                "formation_delivered": float(shares[0][i, j]),
                                "report_delivered": float(shares[1][i, j]),
                                "estimate_delivered": float(shares[2][i, j]),
                            }
                        )
                frac = kept.mean(axis=1)
                success[(label, strategy)] = frac
                critical[(label, strategy)] = critical_range(spec.multiples, frac)
                median[(label, strategy)] = np.median(errors, axis=1)
    load = {name: epoch_load(s) for name, s in spec.topologies}
    return CapacityResult(spec, rows, success, critical, median, load)


def labels(spec: CapacitySpec) -> list[str]:
    return [f"{study}, {name}" for study in spec.studies for name, _ in spec.topologies]


def critical_markdown(r: CapacityResult) -> str:
    """Critical ``ρ`` per strategy (rows) and study × topology (columns)."""
    cols = labels(r.spec)
    lines = ["| strategy | " + " | ".join(cols) + " |", "|" + " --- |" * (1 + len(cols))]
    for s in r.spec.strategies:
        cells = []
        for c in cols:
            crit = r.critical[(c, s)]
            cells.append("none" if crit is None else f"{crit:g} ×")
        lines.append(f"| {s} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def results_markdown(r: CapacityResult) -> str:
    spec = r.spec
    text = [
        "# Capacity: the formation against the network's capacity",
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
        "| topology | states [B] | reports [B] | estimates [B] | control share | c_ap [kbit/s] | c_radio [kbit/s] |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name, ld in r.load.items():
        total = ld["states"] + ld["reports"] + ld["estimates"]
        share = (ld["reports"] + ld["estimates"]) / total
        text.append(
            f"| {name} | {ld['states']:.0f} | {ld['reports']:.0f} | {ld['estimates']:.0f} | "
            f"{share:.0%} | {ld['c_ap'] / 1e3:.1f} | {ld['c_radio'] / 1e3:.1f} |"
        )
    text += ["", "## Critical capacity per strategy", "", critical_markdown(r)]
    text += ["## What the numbers show", "", *what_it_shows(r), ""]
    text += ["## Fraction of seeds keeping the formation, and median final shape error [m]", ""]
    for c in labels(spec):
        text += [f"### {c}", "", "| ρ | " + " | ".join(spec.strategies) + " |"]
        text.append("|" + " --- |" * (1 + len(spec.strategies)))
        for i, m in enumerate(spec.multiples):
            cells = [
                f"{r.success[(c, s)][i]:.2f} ({r.median_error[(c, s)][i]:.3g})"
                for s in spec.strategies
            ]
            text.append(f"| {m:g} | " + " | ".join(cells) + " |")
        text.append("")
    if r.real:
        text += [
            "## Real-process runs (recorded)",
            "",
            "| strategy | ρ | seed | max abs(Δx) | recorded | match | recording |",
            "| --- | --- | --- | --- | --- | --- | --- |",
        ]
        for row in r.real:
            text.append(
                f"| {row['strategy']} | {row['rate_multiple']:g} | {row['seed']} | "
                f"{row['max_diff']} | {row['recorded_diff']} | {row['match']} | {row['recording']} |"
            )
    text += ["", "![success against capacity](phase.png)", ""]
    return "\n".join(text)


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
    out.mkdir(parents=True, exist_ok=True)
    with (out / "runs.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS)
        writer.writeheader()
        for row in r.rows:
            writer.writerow(
                {
                    k: repr(v) if isinstance(v, float) and math.isfinite(v) else v
                    for k, v in row.items()
                }
            )
    (out / "critical.md").write_text(
        "# Critical capacity per strategy (ρ: multiples of the rate the states need)\n\n"
        + critical_markdown(r)
    )
    (out / "results.md").write_text(results_markdown(r))
    plot_range_phase(
        r.success,
        r.critical,
        r.spec.multiples,
        labels(r.spec),
        r.spec.strategies,
        r.spec.threshold_m,
        out / "phase.png",
        xlabel="capacity ρ (× the rate one epoch's states need)",
        columns=len(r.spec.topologies),
    )


__all__ = [
    "COLUMNS",
    "MULTIPLES",
    "STUDIES",
    "CapacityResult",
    "CapacitySpec",
    "capacity_variant",
    "epoch_load",
    "run_capacity",
    "run_capacity_real",
    "write_outputs",
]
