"""The in-process simulator: the model of docs/model.md epoch by epoch, in one process, no Zenoh.

It composes the same cores the services run (``netem.models``, ``agent.control``,
``agent.strategies``, ``leader.mst``, ``leader.blue``, ``leader.rigidity``,
``leader.reference``), so a distributed lockstep run with the same scenario and
seed gives the same numbers.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from agent.epoch import InLinks, agent_epoch
from agent.measurement import relative_measurement
from agent.strategies import LinkMemory
from formation.reference import reference_positions, reference_velocities
from formation.scenario import LEADER_ENDPOINT, Scenario, StrategyName
from leader.epoch import leader_epoch
from leader.rigidity import HealthyRigidity
from netem.models import schedule
from recorder.metrics import error_statistics, formation_error, longest_run, nees, shape_error

Array = npt.NDArray[np.float64]


@dataclass
class SimResult:
    """Everything one simulated run produced; row ``i − 1`` is agent ``i``, ``E`` epochs.

    positions : (E + 1, n, d) true positions [m]
    formation_error, shape_error : (E + 1,) [m]
    estimates : (E, n, d) leader's BLUE (NaN where unobservable); estimate_cov (E, n, d, d)
    delivered : (E, L) formation link ``directed_links[l]`` delivered in time at epoch k
    report_ok, estimate_ok : (E, n) control links delivered in time
    healthy, tree : (E, m) per formation edge
    components, rigidity_rank : (E,)
    substitution_errors : (N, d) ``x̃_j − x_j`` of every substituted variable [m]
    """

    scenario: Scenario
    strategy: StrategyName
    seed: int
    positions: Array
    formation_error: Array
    shape_error: Array
    estimates: Array
    estimate_cov: Array
    observable: npt.NDArray[np.bool_]
    delivered: npt.NDArray[np.bool_]
    report_ok: npt.NDArray[np.bool_]
    estimate_ok: npt.NDArray[np.bool_]
    healthy: npt.NDArray[np.bool_]
    tree: npt.NDArray[np.bool_]
    components: npt.NDArray[np.int64]
    rigidity_rank: npt.NDArray[np.int64]
    substitution_errors: Array
    substitution_epochs: npt.NDArray[np.int64]
    fallbacks: int
    nees_values: Array
    estimation_errors: Array
    extra: dict[str, Any] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        """The headline numbers of the run (what ``formation simulate`` prints)."""
        _, _sub_cov, sub_trace = error_statistics(self.substitution_errors)
        _, _est_cov, est_trace = error_statistics(self.estimation_errors)
        drops = (~self.delivered).sum(axis=0)
        links = self.scenario.directed_links
        return {
            "scenario": self.scenario.name,
            "strategy": self.strategy,
            "seed": self.seed,
            "epochs": int(self.positions.shape[0] - 1),
            "final_formation_error_m": float(self.formation_error[-1]),
            "peak_formation_error_m": float(self.formation_error.max()),
            "final_shape_error_m": float(self.shape_error[-1]),
            "peak_shape_error_m": float(self.shape_error.max()),
            "substitutions": int(self.substitution_errors.shape[0]),
            "substitution_cov_trace_m2": _none_if_nan(sub_trace),
            "fallbacks": self.fallbacks,
            "estimation_cov_trace_m2": _none_if_nan(est_trace),
            "nees_mean": _none_if_nan(
                float(self.nees_values.mean()) if self.nees_values.size else float("nan")
            ),
            "drops": {
                f"{int(a)}->{int(b)}": int(c) for (a, b), c in zip(links, drops, strict=True) if c
            },
            "longest_outage": {
                f"{int(a)}->{int(b)}": longest_run(~self.delivered[:, k])
                for k, (a, b) in enumerate(links)
                if drops[k]
            },
        }


def _none_if_nan(v: float) -> float | None:
    return None if np.isnan(v) else v


def link_schedules(scenario: Scenario, seed: int, n_epochs: int) -> dict[str, npt.NDArray[Any]]:
    """Per-epoch delivery and delay of every formation and control link, from netem's models."""
    links = scenario.directed_links
    delivered = np.zeros((n_epochs, len(links)), dtype=bool)
    delay = np.zeros((n_epochs, len(links)), dtype=np.int64)
    for k, (a, b) in enumerate(links):
        s = schedule(scenario.formation_link_models(int(a), int(b)), seed, int(a), int(b), n_epochs)
        delivered[:, k], delay[:, k] = s.delivered, s.delay_epochs
    n = scenario.n
    report_ok = np.zeros((n_epochs, n), dtype=bool)
    estimate_ok = np.zeros((n_epochs, n), dtype=bool)
    for i in range(1, n + 1):
        up = schedule(scenario.control_link_models(i, "report"), seed, i, LEADER_ENDPOINT, n_epochs)
        down = schedule(
            scenario.control_link_models(i, "estimate"), seed, LEADER_ENDPOINT, i, n_epochs
        )
        report_ok[:, i - 1] = up.delivered & (up.delay_epochs == 0)
        estimate_ok[:, i - 1] = down.delivered & (down.delay_epochs == 0)
    return {
        "delivered": delivered,
        "delay": delay,
        "report_ok": report_ok,
        "estimate_ok": estimate_ok,
    }


def simulate(
    scenario: Scenario,
    strategy: StrategyName | None = None,
    seed: int | None = None,
    epochs: int | None = None,
) -> SimResult:
    """Run ``scenario`` in one process.

    Parameters
    ----------
    scenario : the validated scenario
    strategy : overrides ``scenario.strategy.name``
    seed : overrides ``scenario.seed``
    epochs : overrides ``scenario.epochs``
    """
    strategy = strategy or scenario.strategy.name
    seed = scenario.seed if seed is None else seed
    n_epochs = scenario.epochs if epochs is None else epochs
    n, d, r = scenario.n, scenario.dimension, scenario.leader
    edges, weights, d0 = scenario.edge_array, scenario.weights, scenario.offsets
    links = scenario.directed_links
    src, dst = links[:, 0], links[:, 1]
    in_links = InLinks.of(scenario, np.arange(1, n + 1))
    rigidity = HealthyRigidity(d0, edges)
    period = scenario.control.period_s
    cov = scenario.noise_covariance
    followers = np.arange(n) != r - 1

    sched = link_schedules(scenario, seed, n_epochs)
    on_time = sched["delivered"] & (sched["delay"] == 0)
    ref_x = reference_positions(scenario.reference, d0[r - 1], period, n_epochs)
    ref_v = reference_velocities(ref_x, period)

    x = np.zeros((n_epochs + 1, n, d))
    x[0] = scenario.initial_positions(seed)
    x[0, r - 1] = ref_x[0]
    vel = np.zeros((n, d))
    memory = LinkMemory.empty(len(links), d)
    v_known = np.zeros((n, d))  # each agent's last received v_ref
    late: dict[int, list[tuple[int, int]]] = {}
    for k, link in zip(*np.nonzero(sched["delivered"] & (sched["delay"] > 0)), strict=True):
        late.setdefault(int(k + sched["delay"][k, link]), []).append((int(link), int(k)))

    m = len(edges)
    est = np.full((n_epochs, n, d), np.nan)
    est_cov = np.full((n_epochs, n, d, d), np.nan)
    observable = np.zeros((n_epochs, n), dtype=bool)
    healthy_all = np.zeros((n_epochs, m), dtype=bool)
    tree_all = np.zeros((n_epochs, m), dtype=bool)
    components = np.zeros(n_epochs, dtype=np.int64)
    rig_rank = np.zeros(n_epochs, dtype=np.int64)
    sub_err: list[Array] = []
    sub_epoch: list[npt.NDArray[np.int64]] = []
    sub_pairs: list[npt.NDArray[np.int64]] = []
    nees_vals: list[Array] = []
    est_err: list[Array] = []
    fallbacks = 0

    for k in range(n_epochs):
        xk = x[k]
        for link, sent in late.get(k, []):
            mask = np.zeros(len(links), dtype=bool)
            mask[link] = True
            memory = memory.receive_late(x[sent][src - 1], np.full(len(links), sent), mask)
        arrived = on_time[k]
        z = relative_measurement(xk[dst - 1], xk[src - 1], cov, seed, dst, src, k)

        # Leader: the measurements whose report reached it → tree, BLUE, rigidity.
        known = arrived & sched["report_ok"][k, dst - 1]
        lead = leader_epoch(scenario, known, z, ref_x[k], rigidity)
        res = lead.estimate
        est[k], est_cov[k], observable[k] = res.positions, res.covariances, res.observable
        healthy_all[k], tree_all[k] = lead.healthy, lead.tree
        components[k], rig_rank[k] = lead.components, lead.rigidity_rank
        assert res.covariances is not None  # blue computes them unless told not to
        scored = observable[k] & followers
        if scored.any() and np.any(cov):  # NEES is undefined for ideal (noise-free) sensors
            nees_vals.append(nees(res.positions, res.covariances, xk, scored))
            est_err.append(res.positions[scored] - xk[scored])

        # Estimates reach agents over their control links, with v_ref[k].
        got_est = sched["estimate_ok"][k]
        v_prev = v_known.copy()
        v_known[got_est] = ref_v[k]
        has_estimate = got_est[dst - 1] & observable[k][src - 1]
        step = agent_epoch(
            scenario, strategy, k, in_links, xk, vel, arrived, xk[src - 1], z, memory,
            np.nan_to_num(res.positions[src - 1]), has_estimate, v_prev[dst - 1], v_known,
        )  # fmt: skip
        memory, sub = step.memory, step.substitution
        fallbacks += int(sub.fallback.sum())
        # Every lost variable counts (docs/model.md §7), also those the reference agent substitutes
        # without steering by them: on the default scenario they are the only ones with error.
        lost_sub = sub.substituted
        if lost_sub.any():
            sub_err.append(sub.values[lost_sub] - xk[src[lost_sub] - 1])
            sub_epoch.append(np.full(int(lost_sub.sum()), k))
            sub_pairs.append(links[lost_sub])
        nxt, vel = step.positions, step.velocities
        nxt[r - 1] = ref_x[k + 1]
        x[k + 1] = nxt

    pairs = np.concatenate(sub_pairs) if sub_pairs else np.zeros((0, 2), dtype=np.int64)
    return SimResult(
        scenario=scenario,
        strategy=strategy,
        seed=seed,
        positions=x,
        formation_error=formation_error(x, edges, weights),
        shape_error=shape_error(x, edges, d0),
        estimates=est,
        estimate_cov=est_cov,
        observable=observable,
        delivered=on_time,
        report_ok=sched["report_ok"],
        estimate_ok=sched["estimate_ok"],
        healthy=healthy_all,
        tree=tree_all,
        components=components,
        rigidity_rank=rig_rank,
        substitution_errors=np.concatenate(sub_err) if sub_err else np.zeros((0, d)),
        substitution_epochs=np.concatenate(sub_epoch) if sub_epoch else np.zeros(0, dtype=np.int64),
        fallbacks=fallbacks,
        nees_values=np.concatenate(nees_vals) if nees_vals else np.zeros(0),
        estimation_errors=np.concatenate(est_err) if est_err else np.zeros((0, d)),
        extra={
            "substitution_senders": pairs[:, 0],
            "substitution_receivers": pairs[:, 1],
        },
    )
