"""``formation experiment value``: where filling a lost packet with the leader's estimate pays.

The map is a base case and one-axis slices around it, not a full factorial, so each row
changes one thing a reader can name. The base: the chapter's pentagon (minimally rigid,
docs/model.md §8), link 2–3 down in both directions from epoch 1 (two followers: a link
ending at the reference agent would be filled from a position the leader knows exactly),
the reference on the chapter's line. Each case runs under both controllers (docs/model.md
§3): displacement consensus, which needs only a connected graph, and the distance law,
which needs a rigid one (§2's note, the chapter's §7.2). The slices:

* graph: nothing lost; the redundant pentagon (+ edge 3–4) with 2–3 down, still rigid; 1–2
  down (its other end the reference agent); 3–5 and 4–5 down, agent 5 cut off (unobservable);
* direction: 2–3 lost one way only (2 → 3), the other direction's measurement still reported;
* loss rate: Bernoulli loss on every formation link;
* burstiness: Gilbert–Elliott at the same mean rate, longer bursts;
* control links: with 2–3 down, agent 3's estimates or its reports lost at random;
* team: triangle strips of 8 and 12 agents (minimally rigid), 2–3 down;
* reference: still, and five times faster than the chapter's line.

Every case runs every strategy (the chapter's five and the installed plug-ins) over the same
plan. A run's judged error is its final edge-length error (``formation_error``) under the
distance law, which leaves the formation free to rotate, and its final shape error under
displacement consensus; a run whose law diverged (a command not finite) counts as lost.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
import pandas as pd

from formation.errors import PluginFailure
from formation.graph import is_connected
from formation.plugin_api import all_strategies
from formation.rigidity import batched_ranks, expected_rigidity_rank, rigidity_matrix
from formation.scenario import Scenario, StrategyName, load_dict
from testbed.experiments.grid import Variant, run_grid
from testbed.experiments.loss_variants import gilbert_elliott_at
from testbed.sim.batch import BatchResult
from testbed.sim.plan import BatchPlan, plan_batch

Array = npt.NDArray[Any]
GAINS = {"displacement": 0.2, "distance": 0.05}  # ε [1/s]; the distance law's [1/(m² s)]
CONTROLLERS = tuple(GAINS)
LOST = (2, 3)  # the base case's lost link
EPOCHS = 300  # the distance law settles in about 150 epochs at its gain
KEEP_M = 0.05  # [m] a run keeps the formation when its judged final error is under this
LOSS_RATES = (0.1, 0.3, 0.5)
BURST_RATE, BURSTS = 0.3, (4.0, 16.0)  # Gilbert–Elliott mean loss and mean bursts [epochs]
CONTROL_LOSS = 0.5
TEAM_SIZES = (8, 12)
FAST = 5.0  # the fast reference: this many times the chapter's velocity
COLUMNS = (
    "controller",
    "axis",
    "case",
    "strategy",
    "seed",
    "final_error_m",
    "kept",
    "diverged",
    "fallbacks",
    "rigid_share",
    "connected_share",
)


@dataclass(frozen=True)
class Case:
    """A row of the map: its slice (``axis``), its label and how it changes the base.

    ``shape`` names the scenario it changes (cases of one shape share a plan); ``network``
    gives that scenario's network section.
    """

    axis: str
    label: str
    network: dict[str, Any]
    shape: str = "pentagon"


def _down(*links: tuple[int, int], direction: str = "both") -> list[dict[str, Any]]:
    outage = [{"model": "outage", "start": 1}]
    return [{"between": list(p), "direction": direction, "models": outage} for p in links]


def _control(direction: str) -> list[dict[str, Any]]:
    lossy = [{"model": "bernoulli", "p_loss": CONTROL_LOSS}]
    return [{"agent": LOST[1], "direction": direction, "models": lossy}]


def _every_link(spec: dict[str, Any]) -> dict[str, Any]:
    return {"formation_default": [spec]}


def cases() -> tuple[Case, ...]:
    """The base case and the slices around it, in the order the map shows them."""
    base = {"links": _down(LOST)}
    out = [
        Case("base", "2–3 down", base),
        Case("graph", "nothing lost", {}),
        Case("graph", "redundant (+3–4), 2–3 down", base, shape="redundant"),
        Case("graph", "1–2 down (reference end)", {"links": _down((1, 2))}),
        Case("graph", "3–5, 4–5 down (agent 5 cut off)", {"links": _down((3, 5), (4, 5))}),
        Case("direction", "2–3 down one way (2→3)", {"links": _down(LOST, direction="forward")}),
    ]
    out += [
        Case("loss rate", f"Bernoulli {p:g} on every link", _every_link(_bernoulli(p)))
        for p in LOSS_RATES
    ]
    out += [
        Case("burst", f"Gilbert–Elliott {BURST_RATE:g}, bursts {b:g}", _every_link(_bursty(b)))
        for b in BURSTS
    ]
    out += [
        Case(
            "control links",
            f"2–3 down, agent 3's {phase}s lost {CONTROL_LOSS:g}",
            {**base, "control": _control(phase)},
        )
        for phase in ("estimate", "report")
    ]
    out += [Case("team", f"{n} agents, 2–3 down", base, shape=f"strip{n}") for n in TEAM_SIZES]
    out += [
        Case("reference", "still reference, 2–3 down", base, shape="still"),
        Case("reference", f"reference {FAST:g}× faster, 2–3 down", base, shape="fast"),
    ]
    return tuple(out)


def _bernoulli(p: float) -> dict[str, Any]:
    return {"model": "bernoulli", "p_loss": p}


def _bursty(burst: float) -> dict[str, Any]:
    return {"model": "gilbert_elliott", **gilbert_elliott_at(BURST_RATE, burst), "1-h": 1.0}


def strip(paper: Scenario, n: int) -> Scenario:
    """A triangle strip of ``n`` agents on a circle (agent ``k`` joined to ``k − 1`` and
    ``k − 2``: ``2n − 3`` edges, minimally rigid), its sides as long as the pentagon's."""
    side = float(np.linalg.norm(paper.offsets[0] - paper.offsets[1]))
    radius = side / (2 * np.sin(np.pi / n))
    angles = np.pi / 2 + 2 * np.pi * np.arange(n) / n
    data = paper.model_dump(by_alias=True)
    data["agents"] = [
        {"id": i + 1, "offset": [radius * np.cos(a), radius * np.sin(a)]}
        for i, a in enumerate(angles)
    ]
    data["edges"] = [[1, 2]] + [[k - j, k] for k in range(3, n + 1) for j in (2, 1)]
    data["name"] = f"strip{n}"
    return load_dict(data, source=f"triangle strip of {n} agents")


def redundant(paper: Scenario) -> Scenario:
    """The pentagon plus edge 3–4: one edge more than minimally rigid."""
    data = paper.model_dump(by_alias=True)
    data["edges"] = [list(e.between) for e in paper.edges] + [[3, 4]]
    data["name"] = "pentagon+34"
    return load_dict(data, source="pentagon + edge 3-4")


def shaped(paper: Scenario, shape: str, controller: str, epochs: int = EPOCHS) -> Scenario:
    """The scenario a case's ``shape`` names, under ``controller`` at its gain."""
    control = {**paper.control.model_dump(), "controller": controller, "gain": GAINS[controller]}
    s = paper.with_overrides(control=control, network={}, epochs=epochs)
    if shape == "redundant":
        return redundant(s)
    if shape.startswith("strip"):
        return strip(s, int(shape.removeprefix("strip")))
    if shape in ("still", "fast"):
        ref = s.reference.model_dump()
        if shape == "still":
            return s.with_overrides(reference={"kind": "static"})
        return s.with_overrides(reference={**ref, "velocity": [FAST * v for v in ref["velocity"]]})
    return s


def judge(controller: str) -> Callable[[BatchResult], dict[str, Array]]:
    """A cell's judged final error (edge lengths under the distance law, shape under
    displacement consensus; inf when it diverged), kept, and estimate's fallbacks to hold."""

    def measure(res: BatchResult) -> dict[str, Array]:
        err = res.formation_error if controller == "distance" else res.shape_error
        final = np.asarray(err[-1], dtype=float)
        diverged = ~np.isfinite(final)
        final = np.where(diverged, np.inf, final)
        return {
            "final_error_m": final,
            "kept": final < KEEP_M,
            "diverged": diverged,
            "fallbacks": np.asarray(res.fallbacks),
        }

    return measure


def healthy_shares(plan: BatchPlan) -> dict[str, Array]:
    """(B,) the share of epochs 1.. in which the graph of the links delivered both ways is
    rigid, and connected: what ``drop`` leaves the controller."""
    base = plan.base
    links = {tuple(map(int, p)): c for c, p in enumerate(base.directed_links)}
    edges = base.edge_array
    both = np.array([[links[(i, j)], links[(j, i)]] for i, j in edges.tolist()])
    healthy = plan.on_time[1:, :, both[:, 0]] & plan.on_time[1:, :, both[:, 1]]  # (E-1, B, m)
    patterns, inverse = np.unique(healthy.reshape(-1, len(edges)), axis=0, return_inverse=True)
    r = rigidity_matrix(base.offsets, edges)
    ranks = batched_ranks(r[None, :, :] * patterns[:, :, None])
    rigid = ranks == expected_rigidity_rank(base.n, base.dimension)
    connected = np.array([is_connected(base.n, edges[p]) for p in patterns])
    shape = healthy.shape[:2]
    return {
        "rigid_share": rigid[inverse.reshape(-1)].reshape(shape).mean(axis=0),
        "connected_share": connected[inverse.reshape(-1)].reshape(shape).mean(axis=0),
    }


@dataclass(frozen=True)
class ValueSpec:
    scenario: Scenario
    seeds: tuple[int, ...] = tuple(range(1, 11))
    strategies: tuple[StrategyName, ...] = field(default_factory=all_strategies)
    cases: tuple[Case, ...] = field(default_factory=cases)
    controllers: tuple[str, ...] = CONTROLLERS
    epochs: int = EPOCHS


def run_value(spec: ValueSpec, log: Callable[[str], None] = print) -> pd.DataFrame:
    """Every controller, case, strategy and seed on the batch simulator: a row per cell."""
    frames = []
    for controller in spec.controllers:
        for shape in dict.fromkeys(c.shape for c in spec.cases):
            s = shaped(spec.scenario, shape, controller, spec.epochs)
            variants = [
                Variant(
                    {"controller": controller, "axis": c.axis, "case": c.label},
                    s.with_overrides(network=c.network),
                )
                for c in spec.cases
                if c.shape == shape
            ]
            log(f"value: {controller}, {shape} ({len(variants)} cases) …")
            for strategy in spec.strategies:
                frames.append(_cells(variants, spec.seeds, strategy, controller))
    frame = pd.concat(frames, ignore_index=True)
    order = {c.label: k for k, c in enumerate(spec.cases)}
    frame["_order"] = frame["case"].map(order)
    frame = frame.sort_values(["controller", "_order", "strategy", "seed"], kind="stable")
    return frame.drop(columns="_order").reset_index(drop=True)


def _cells(
    variants: Sequence[Variant], seeds: Sequence[int], strategy: StrategyName, controller: str
) -> pd.DataFrame:
    """One strategy's cells. Where the law diverges in a batch (the command stops being
    finite), each variant runs alone, then each of its seeds, so that only the members that
    diverged count as such."""
    measure = judge(controller)
    try:
        return run_grid(variants, seeds, [strategy], measure, planned=healthy_shares)
    except PluginFailure:
        if len(variants) == 1 and len(seeds) == 1:
            return _diverged(variants[0], seeds[0], strategy)
    if len(variants) > 1:
        parts = [_cells([v], seeds, strategy, controller) for v in variants]
    else:
        parts = [_cells(variants, [seed], strategy, controller) for seed in seeds]
    return pd.concat(parts, ignore_index=True)


def _diverged(v: Variant, seed: int, strategy: StrategyName) -> pd.DataFrame:
    shares = healthy_shares(plan_batch(v.scenario, [seed]))
    row = {**v.keys, "strategy": strategy, "seed": seed, "final_error_m": np.inf}
    row |= {"kept": False, "diverged": True, "fallbacks": -1}
    row |= {k: float(a[0]) for k, a in shares.items()}
    return pd.DataFrame([row])


__all__ = [
    "COLUMNS",
    "CONTROLLERS",
    "EPOCHS",
    "GAINS",
    "KEEP_M",
    "Case",
    "ValueSpec",
    "cases",
    "healthy_shares",
    "judge",
    "redundant",
    "run_value",
    "shaped",
    "strip",
]
