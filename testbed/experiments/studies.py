"""The comparisons the chapter does not make, each a function from a scenario to numbers.

* :func:`controller_study`: §7.2 made testable (docs/model.md §2 note): links dropped for the whole
  run, the displacement controller against the distance-based one; the first needs a connected
  healthy graph, the second a rigid one.
* :func:`estimator_study`: the BLUE on the Kruskal tree against every healthy edge (docs/model.md §5):
  predicted and empirical covariance trace, NEES.
* :func:`alpha_study`: how ``α`` of ``blend`` moves the substitution error and the formation.
* :func:`dynamic_study`: an agent leaves at epoch ``a`` and another joins at ``b``, as the
  scenario's events (``formation.events``, the same a real run carries out); the leader's tree
  and the estimates follow the team taking part.

Every function runs batches (``testbed.sim.batch``) over seeds and returns a small frozen result with
a ``markdown()`` table; nothing here writes files.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from analysis import error_statistics, team_shape_error
from formation.graph import is_connected
from formation.markdown import table
from formation.rigidity import expected_rigidity_rank, rigidity_rank
from formation.scenario import STRATEGIES, Scenario, StrategyName, load_dict
from recorder import KEEP_M  # one threshold for the run reports and the experiments
from testbed.experiments.grid import KEEP_FRACTION
from testbed.experiments.loss_variants import with_loss
from testbed.sim.batch import BatchResult, plan_batch, run_batch

Array = npt.NDArray[np.float64]


def fmt(v: float, spec: str = ".3g") -> str:
    """A number for a table; ``-`` for NaN."""
    return "-" if v is None or not np.isfinite(v) else format(v, spec)


def mean_std(v: Array, spec: str = ".3g") -> str:
    v = np.asarray(v, dtype=float)
    return f"{fmt(float(np.mean(v)), spec)} ± {fmt(float(np.std(v)), spec)}"


def drop_links(scenario: Scenario, links: Sequence[tuple[int, int]], start: int = 0) -> Scenario:
    """``scenario`` with ``links`` down in both directions from epoch ``start`` on."""
    net = scenario.network.model_dump(by_alias=True)
    net["links"] = [
        {"between": list(p), "models": [{"model": "outage", "start": start}]} for p in links
    ]
    return scenario.with_overrides(network=net)


def lossy_links(scenario: Scenario, links: Sequence[tuple[int, int]], p_loss: float) -> Scenario:
    """``scenario`` with Bernoulli loss ``p_loss`` on ``links`` (both directions) for the whole run."""
    net = scenario.network.model_dump(by_alias=True)
    net["links"] = [
        {"between": list(p), "models": [{"model": "bernoulli", "p_loss": p_loss}]} for p in links
    ]
    return scenario.with_overrides(network=net)


def substitution_trace(
    res: BatchResult, first_epoch: int = 0, last_epoch: int | None = None
) -> float:
    """tr Cov of every substitution error of every member in epochs ``[first, last)`` [m²]."""
    sel = res.sub_epoch >= first_epoch
    if last_epoch is not None:
        sel &= res.sub_epoch < last_epoch
    return error_statistics(res.sub_error[sel])[2]


# ------------------------------------------------------------------------------ §7.2 controllers


@dataclass(frozen=True)
class ControllerCase:
    label: str
    dropped: tuple[tuple[int, int], ...]
    rigid: bool
    connected: bool
    final_error: dict[str, Array]  # controller → (S,) final formation error [m]

    def kept(self, controller: str) -> float:
        return float(np.mean(self.final_error[controller] < KEEP_M))


@dataclass(frozen=True)
class ControllerStudy:
    cases: tuple[ControllerCase, ...]
    gains: dict[str, float]
    epochs: int
    seeds: tuple[int, ...]

    def predicted(self, case: ControllerCase, controller: str) -> bool:
        """§7.2: the distance controller needs rigidity, the displacement one connectivity."""
        return case.rigid if controller == "distance" else case.connected

    def holds(self) -> bool:
        return all(
            (c.kept(k) >= KEEP_FRACTION) == self.predicted(c, k)
            for c in self.cases
            for k in self.gains
        )

    def markdown(self) -> str:
        header = ["dropped for the whole run", "healthy graph rigid", "connected", "controller"]
        header += ["gain", "final formation error [m]", "seeds kept", "kept", "§7.2 predicts"]
        rows = []
        for c in self.cases:
            for k, gain in self.gains.items():
                kept = c.kept(k)
                rows.append(
                    [
                        c.label,
                        _yes(c.rigid),
                        _yes(c.connected),
                        k,
                        f"{gain:g}",
                        mean_std(c.final_error[k]),
                        f"{kept:.0%}",
                        _yes(kept >= KEEP_FRACTION),
                        "kept" if self.predicted(c, k) else "lost",
                    ]
                )
        return table(header, rows)


def _yes(value: bool) -> str:
    return "yes" if value else "no"


def redundant_pentagon(paper: Scenario) -> Scenario:
    """The paper's pentagon plus edge 3–4: one edge more than minimally rigid."""
    data = paper.model_dump(by_alias=True)
    data["edges"] = [list(e.between) for e in paper.edges] + [[3, 4]]
    data["name"] = "pentagon+34"
    data["control"] = {**data["control"], "gain": 0.2}  # max degree 4
    return load_dict(data, source="pentagon + edge 3-4")


def controller_study(
    paper: Scenario, seeds: Sequence[int], epochs: int = 300, gains: dict[str, float] | None = None
) -> ControllerStudy:
    """Drop chosen links for the whole run (strategy ``drop``) under both controllers."""
    gains = gains or {"displacement": 0.2, "distance": 0.05}
    base = drop_links(paper, [])
    plus = redundant_pentagon(base)
    cases_in: list[tuple[str, Scenario, tuple[tuple[int, int], ...]]] = [
        ("none", base, ()),
        ("1–2", base, ((1, 2),)),
        ("2–3", base, ((2, 3),)),
        ("3–5", base, ((3, 5),)),
        ("3–5 and 4–5", base, ((3, 5), (4, 5))),
        ("none (pentagon + 3–4)", plus, ()),
        ("1–2 (pentagon + 3–4)", plus, ((1, 2),)),
    ]
    cases = []
    for label, scen, dropped in cases_in:
        edges = scen.edge_array
        keep = [k for k, (i, j) in enumerate(edges) if (int(i), int(j)) not in dropped]
        rank = rigidity_rank(scen.offsets, edges[keep])
        rigid = rank == expected_rigidity_rank(scen.n, scen.dimension)
        finals: dict[str, Array] = {}
        for controller, gain in gains.items():
            s = drop_links(
                scen.with_overrides(
                    control={**scen.control.model_dump(), "controller": controller, "gain": gain}
                ),
                dropped,
            )
            with np.errstate(all="ignore"):
                res = run_batch(plan_batch(s, seeds, epochs), "drop", detail=False)
            finals[controller] = np.nan_to_num(res.formation_error[-1], nan=np.inf)
        cases.append(
            ControllerCase(label, dropped, bool(rigid), is_connected(scen.n, edges[keep]), finals)
        )
    return ControllerStudy(tuple(cases), gains, epochs, tuple(seeds))


# ------------------------------------------------------------------------------ tree vs healthy


@dataclass(frozen=True)
class EstimatorRow:
    label: str
    predicted: dict[str, float]  # edges rule → mean tr Cov(x̂_i) over observable followers [m²]
    empirical: dict[str, float]  # edges rule → tr of the pooled estimation error covariance [m²]
    nees: dict[str, float]
    final_error: dict[str, Array]


@dataclass(frozen=True)
class EstimatorStudy:
    rows: tuple[EstimatorRow, ...]
    epochs: int
    seeds: tuple[int, ...]

    def markdown(self) -> str:
        header = ["scenario", "tr Cov predicted, tree [m²]", "healthy [m²]", "ratio healthy/tree"]
        header += ["tr Cov empirical, tree [m²]", "healthy [m²]", "ratio", "NEES tree"]
        header += ["NEES healthy", "final formation error tree [m]", "healthy [m]"]
        rows = []
        for r in self.rows:
            p, e = r.predicted, r.empirical
            rows.append(
                [
                    r.label,
                    fmt(p["tree"]),
                    fmt(p["healthy"]),
                    fmt(p["healthy"] / p["tree"]),
                    fmt(e["tree"]),
                    fmt(e["healthy"]),
                    fmt(e["healthy"] / e["tree"]),
                    fmt(r.nees["tree"]),
                    fmt(r.nees["healthy"]),
                    mean_std(r.final_error["tree"]),
                    mean_std(r.final_error["healthy"]),
                ]
            )
        return table(header, rows)


def estimator_study(
    scenarios: Sequence[tuple[str, Scenario]], seeds: Sequence[int], epochs: int = 200
) -> EstimatorStudy:
    """Strategy ``estimate`` with the BLUE on the tree and on every healthy edge."""
    rows = []
    for label, scen in scenarios:
        pred, emp, nees_m, final = {}, {}, {}, {}
        for rule in ("tree", "healthy"):
            s = scen.with_overrides(estimator={**scen.estimator.model_dump(), "edges": rule})
            res = run_batch(plan_batch(s, seeds, epochs), "estimate", rigidity=False)
            assert res.estimate_cov is not None and res.observable is not None
            follower = np.arange(s.n) != s.reference_agent - 1
            mask = res.observable & follower
            traces = np.trace(res.estimate_cov, axis1=-2, axis2=-1)
            pred[rule] = float(traces[mask].mean())
            members = [res.member(b) for b in range(res.size)]
            errs = np.concatenate([m.estimation_errors for m in members])
            emp[rule] = error_statistics(errs)[2]
            nees_m[rule] = float(np.concatenate([m.nees_values for m in members]).mean())
            final[rule] = res.formation_error[-1]
        rows.append(EstimatorRow(label, pred, emp, nees_m, final))
    return EstimatorStudy(tuple(rows), epochs, tuple(seeds))


# ------------------------------------------------------------------------------ α of blend


@dataclass(frozen=True)
class AlphaCurve:
    label: str
    alphas: Array
    values: Array  # the measured quantity per α
    unit: str

    @property
    def best(self) -> float:
        return float(self.alphas[int(np.nanargmin(self.values))])

    @property
    def relative(self) -> Array:
        """Values over the value at α = 1 (``blend`` with α = 1 is ``estimate``)."""
        return np.asarray(self.values / self.values[-1], dtype=np.float64)


@dataclass(frozen=True)
class AlphaStudy:
    curves: tuple[AlphaCurve, ...]
    seeds: tuple[int, ...]

    def markdown(self) -> str:
        rows = [
            [f"{a:g}", *(f"{fmt(c.values[i])} ({c.relative[i]:.2f})" for c in self.curves)]
            for i, a in enumerate(self.curves[0].alphas)
        ]
        rows.append(["**best α**", *(f"**{c.best:g}**" for c in self.curves)])
        return table(["α", *(f"{c.label} [{c.unit}]" for c in self.curves)], rows)


DEFAULT_ALPHAS = (0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)


def alpha_study(
    paper: Scenario,
    seeds: Sequence[int],
    alphas: Sequence[float] = DEFAULT_ALPHAS,
    long_epochs: int = 500,
    lossy_epochs: int = 200,
    p_loss: float = 0.3,
) -> AlphaStudy:
    """Blend's substitution error (and, with every link lossy, the formation) against ``α``."""
    a = np.asarray(alphas, dtype=float)
    if a[-1] != 1.0:
        raise ValueError(f"alphas must end with 1.0 (the estimate baseline), got {a[-1]:g}")
    chapter, steady, lossy_sub, lossy_final = [], [], [], []
    lossy = with_loss(paper, "bernoulli", p_loss)
    plan_long = plan_batch(paper, seeds, long_epochs)
    plan_lossy = plan_batch(lossy, seeds, lossy_epochs)
    for alpha in a.tolist():
        strat = {"name": "blend", "params": {"blend": {"alpha": alpha}}}
        res = run_batch(
            _rebase(plan_long, paper.with_overrides(strategy=strat)), "blend", rigidity=False
        )
        chapter.append(substitution_trace(res, 0, paper.epochs))
        steady.append(substitution_trace(res, 20))
        res = run_batch(
            _rebase(plan_lossy, lossy.with_overrides(strategy=strat)), "blend", rigidity=False
        )
        lossy_sub.append(substitution_trace(res, 20))
        lossy_final.append(float(np.mean(res.formation_error[-1])))
    n = f"{len(seeds)} seeds"
    return AlphaStudy(
        (
            AlphaCurve(
                f"link 1–2 failed, tr Cov subst., epochs 0–{paper.epochs - 1}, {n}",
                a,
                np.array(chapter),
                "m²",
            ),
            AlphaCurve(
                f"link 1–2 failed, tr Cov subst., epochs 20–{long_epochs - 1}",
                a,
                np.array(steady),
                "m²",
            ),
            AlphaCurve(
                f"all links p = {p_loss:g}, tr Cov subst., epochs 20–{lossy_epochs - 1}",
                a,
                np.array(lossy_sub),
                "m²",
            ),
            AlphaCurve(
                f"all links p = {p_loss:g}, final formation error (mean)",
                a,
                np.array(lossy_final),
                "m",
            ),
        ),
        tuple(seeds),
    )


def _rebase(plan: Any, scenario: Scenario) -> Any:
    """The same draws with another strategy block (α): the plan's base carries it."""
    return replace(plan, base=scenario, scenarios=tuple(scenario for _ in plan.scenarios))


# ------------------------------------------------------------------------------ dynamic formation


def dynamic_team(
    paper: Scenario, leave: tuple[int, int] | None = None, join: tuple[int, int] | None = None
) -> Scenario:
    """The paper's pentagon plus agent 6 below edge 3–4 (edges 3–6, 4–6): 6 agents, 9 = 2n − 3 edges.

    ``leave``, ``join``: ``(agent, epoch)`` events (a joining agent is absent until then).
    """
    data = paper.model_dump(by_alias=True)
    data["name"] = "pentagon-join-leave"
    data["agents"] = [*data["agents"], {"id": 6, "offset": [0.0, -1.6]}]
    data["edges"] = [list(e.between) for e in paper.edges] + [[3, 6], [4, 6]]
    data["control"] = {**data["control"], "gain": 0.2}  # max degree 4
    events = [] if leave is None else [{"epoch": leave[1], "agent": leave[0], "action": "leave"}]
    if join is not None:
        events.append({"epoch": join[1], "agent": join[0], "action": "join"})
    data["events"] = events
    return load_dict(data, source="dynamic team")


@dataclass(frozen=True)
class DynamicStudy:
    scenario: Scenario
    leave: tuple[int, int]  # (agent, epoch)
    join: tuple[int, int]
    shape_error: dict[str, Array]  # strategy → (E + 1, S) over the edges active at each epoch [m]
    tree_edges: Array  # (E,) leader's tree size (seed 0; deliveries do not depend on the seed here)
    observable: Array  # (E,) observable agents
    seeds: tuple[int, ...]

    def settle(self, strategy: str, after: int, below: float = 0.02) -> float:
        """Epochs after ``after`` until the median shape error stays under ``below``."""
        med = np.median(self.shape_error[strategy], axis=1)
        tail = med[after:]
        above = np.flatnonzero(~(tail < below))
        if above.size == 0:
            return 0.0
        if above[-1] == tail.size - 1:
            return float("inf")
        return float(above[-1] + 1)

    def markdown(self) -> str:
        (la, ka), (lj, kj) = self.leave, self.join
        header = ["strategy", f"median shape error before epoch {ka} [m]"]
        header += [f"peak after agent {la} leaves [m]", f"just before agent {lj} joins [m]"]
        header += ["peak after the join [m]", "epochs to settle < 0.02 m", "final [m]"]
        rows = []
        for s, v in self.shape_error.items():
            med = np.median(v, axis=1)
            rows.append(
                [
                    s,
                    fmt(med[ka - 1]),
                    fmt(med[ka:kj].max()),
                    fmt(med[kj - 1]),
                    fmt(med[kj:].max()),
                    fmt(self.settle(s, kj), ".0f"),
                    fmt(med[-1]),
                ]
            )
        return table(header, rows)


def dynamic_study(
    paper: Scenario,
    seeds: Sequence[int],
    leave: tuple[int, int] = (5, 20),
    join: tuple[int, int] = (6, 35),
    epochs: int = 80,
    strategies: Sequence[StrategyName] = STRATEGIES,
) -> DynamicStudy:
    """Agent ``leave[0]`` leaves at epoch ``leave[1]``; agent ``join[0]`` joins at ``join[1]``."""
    team = dynamic_team(paper, leave, join).with_overrides(epochs=epochs)
    plan = plan_batch(team, seeds)
    edges = team.edge_array
    taking_part = team.membership.present[:, None, :]  # (E + 1, 1, n): every seed alike
    shape: dict[str, Array] = {}
    tree_edges = observable = np.zeros(0)
    for s in strategies:
        res = run_batch(plan, s, rigidity=False)
        shape[s] = team_shape_error(res.positions, edges, team.offsets, taking_part)  # (E + 1, S)
        assert res.tree is not None and res.observable is not None
        tree_edges = res.tree[:, 0].sum(axis=1).astype(float)
        observable = res.observable[:, 0].sum(axis=1).astype(float)
    return DynamicStudy(team, leave, join, shape, tree_edges, observable, tuple(seeds))


__all__ = [
    "KEEP_M",
    "AlphaStudy",
    "ControllerStudy",
    "DynamicStudy",
    "EstimatorStudy",
    "alpha_study",
    "controller_study",
    "drop_links",
    "dynamic_study",
    "dynamic_team",
    "estimator_study",
    "lossy_links",
    "mean_std",
    "redundant_pentagon",
    "substitution_trace",
]
