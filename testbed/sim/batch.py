"""The simulator's epoch loop: many seeds (and network variants) of one scenario at once, one process.

:func:`run_batch` is the only epoch loop: :func:`testbed.sim.simulate.simulate` is a batch of one
seed. The members of a batch (``B`` pairs of a network variant and a seed, see
``testbed.sim.plan``) advance together through the cores the services run, each over an extra
batch axis:

* the agents (docs/model.md §3, §6): agents and links of every member are flattened into the rows of
  :func:`agent.epoch.agent_epoch`, the function an agent process runs on its own in-links;
* the leader (docs/model.md §4–§5): :class:`leader.epoch.Leader`, whose batch of one is what the
  leader process runs (Kruskal over the disjoint union of the members' graphs, the BLUE's path sums
  for all tree members in one pass).

Each member gets the floats it gets alone, so a batch, a lone ``simulate`` and a distributed
lockstep run of the same scenario and seed agree bit for bit. Cost: the noise, the schedules and the
initial positions do not depend on the strategy, so a plan is built once and run for every strategy.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from agent import (
    AgentStep,
    InLinks,
    LinkMemory,
    Substitution,
    agent_epoch,
    reference_heading,
    state_width,
)
from analysis import Substitutions, formation_error, nees, shape_error, team_errors
from formation.errors import BatchError
from formation.reference import reference_positions, reference_velocities
from formation.robots import initial_headings
from formation.scenario import StrategyName
from leader import HealthyRigidity, Leader, LeaderEpochs
from testbed.sim.bodies import RobotRows
from testbed.sim.plan import VARIANT_FIELDS, BatchPlan, newest_late, plan_batch
from testbed.sim.presence import Presence
from testbed.sim.ranged import RangedEpochs
from testbed.sim.result import SimResult

Array = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]
Ints = npt.NDArray[np.int64]


@dataclass
class BatchResult:
    """What a batch produced; axis ``B`` is the member, row ``i − 1`` of ``n`` is agent ``i``.

    positions : (E + 1, B, n, d) true positions [m]; formation_error, shape_error : (E + 1, B) [m]
    delivered : (E, B, L) formation link delivered in time
    report_ok, estimate_ok : (E, B, n) control links delivered in time (the plan's, and the
    ranged members' as the epochs decided them)
    headings : (E + 1, B, n) [rad] and saturated : (E, B, n) sub-steps with a clipped speed,
    unicycle dynamics only
    With ``detail``: estimates (E, B, n, d) (NaN where unobservable), estimate_cov
    (E, B, n, d, d), observable (E, B, n), healthy and tree (E, B, m), components and
    rigidity_rank (E, B) (−1 unknown), rigid (E, B) (1, 0; −1 unknown), and every substitution as (member, epoch, link, error (N, d), value (N, d), fallback).
    """

    plan: BatchPlan
    strategy: StrategyName
    positions: Array
    formation_error: Array
    shape_error: Array
    delivered: Mask
    fallbacks: Ints
    detail: bool
    estimates: Array | None = None
    estimate_cov: Array | None = None
    observable: Mask | None = None
    healthy: Mask | None = None
    tree: Mask | None = None
    components: Ints | None = None
    rigidity_rank: Ints | None = None
    rigid: Ints | None = None
    report_ok: Mask | None = None
    estimate_ok: Mask | None = None
    headings: Array | None = None
    saturated: Ints | None = None
    sub_member: Ints = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    sub_epoch: Ints = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    sub_link: Ints = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    sub_error: Array = field(default_factory=lambda: np.zeros((0, 0)))
    sub_value: Array = field(default_factory=lambda: np.zeros((0, 0)))
    sub_fallback: Mask = field(default_factory=lambda: np.zeros(0, dtype=bool))
    # member → (epoch, column, cause code) of each packet the shared air dropped
    air_drops: dict[int, list[tuple[int, int, int]]] = field(default_factory=dict)

    @property
    def size(self) -> int:
        return self.plan.size

    def team_errors(self) -> tuple[Array, Array]:
        """Formation and shape error (E + 1, B) [m] of the team (:func:`analysis.team_errors`,
        in the team: who publishes ``x[k]``, as in :meth:`member`'s record).

        An agent out of the team (left, crashed, not yet joined) stands where it last was
        while the team moves on, so its edges would count a team that holds its shape as
        losing it (docs/model.md §7). Without events: :attr:`formation_error`,
        :attr:`shape_error`.
        """
        team = self.plan.team
        if team is None:
            return self.formation_error, self.shape_error
        base = self.plan.base
        return team_errors(
            self.positions,
            team.published[:, None, :],
            self.formation_error,
            self.shape_error,
            base.edge_array,
            base.weights,
            base.offsets,
        )

    def member(self, b: int) -> SimResult:
        """Member ``b`` as the one-seed simulator's :class:`SimResult` (needs ``detail``)."""
        if not self.detail:
            raise BatchError(
                f"member({b})", "the batch ran without detail; run it with detail=True"
            )
        assert self.estimates is not None and self.estimate_cov is not None
        assert self.observable is not None and self.healthy is not None and self.tree is not None
        assert self.components is not None and self.rigidity_rank is not None
        assert self.rigid is not None
        plan = self.plan
        base = plan.base
        d, r = base.dimension, base.reference_agent
        est, cov, obs = self.estimates[:, b], self.estimate_cov[:, b], self.observable[:, b]
        x = self.positions[:, b]
        scored = obs & (np.arange(base.n) != r - 1)[None, :]
        nees_vals: list[Array] = []
        est_err: list[Array] = []
        if np.any(base.noise_covariance):  # NEES is undefined for ideal (noise-free) sensors
            for k in np.flatnonzero(scored.any(axis=1)).tolist():
                nees_vals.append(nees(est[k], cov[k], x[k], scored[k]))
                est_err.append(est[k][scored[k]] - x[k][scored[k]])
        sel = self.sub_member == b
        pairs = base.directed_links[self.sub_link[sel]]
        report_ok = plan.report_ok if self.report_ok is None else self.report_ok
        estimate_ok = plan.estimate_ok if self.estimate_ok is None else self.estimate_ok
        return SimResult(
            label=self.strategy,
            scenario=plan.scenarios[b],
            strategy=self.strategy,
            seed=int(plan.seeds[b]),
            positions=x,
            formation_error=self.formation_error[:, b],
            shape_error=self.shape_error[:, b],
            estimates=est,
            estimate_cov=cov,
            observable=obs,
            delivered=self.delivered[:, b],
            report_ok=report_ok[:, b],
            estimate_ok=estimate_ok[:, b],
            healthy=self.healthy[:, b],
            tree=self.tree[:, b],
            components=self.components[:, b],
            rigidity_rank=self.rigidity_rank[:, b],
            rigid=self.rigid[:, b],
            substitution_errors=self.sub_error[sel] if sel.any() else np.zeros((0, d)),
            substitutions=Substitutions(
                epoch=self.sub_epoch[sel],
                agent=pairs[:, 1].astype(np.int64),
                neighbour=pairs[:, 0].astype(np.int64),
                fallback=self.sub_fallback[sel],
                values=self.sub_value[sel] if sel.any() else np.zeros((0, d)),
            ),
            fallbacks=int(self.fallbacks[b]),
            air_drops=tuple(self.air_drops.get(b, ())),
            nees_values=np.concatenate(nees_vals) if nees_vals else np.zeros(0),
            estimation_errors=np.concatenate(est_err) if est_err else np.zeros((0, d)),
            headings=None if self.headings is None else self.headings[:, b],
            saturated=None if self.saturated is None else self.saturated[:, b],
        )


def run_batch(
    plan: BatchPlan, strategy: StrategyName, *, detail: bool = True, rigidity: bool = True
) -> BatchResult:
    """Run every member of ``plan`` with ``strategy``, epoch by epoch (docs/model.md §3–§6).

    Parameters
    ----------
    plan : the members and their strategy-independent inputs (``testbed.sim.plan.plan_batch``)
    strategy : the loss strategy every member runs
    detail : keep the leader's per-epoch outputs and the substitutions (``member()`` needs it)
    rigidity : with ``detail``, the rigidity rank of each healthy subgraph

    Returns
    -------
    BatchResult
    """
    base = plan.base
    size, n_epochs = plan.size, plan.epochs
    n, d, r = base.n, base.dimension, base.reference_agent
    edges, d0 = base.edge_array, base.offsets
    links = base.directed_links
    n_links = len(links)
    src, dst = links[:, 0], links[:, 1]
    src0, dst0 = src - 1, dst - 1  # 0-based, once for every epoch's gathers
    ref_x = reference_positions(base.reference, d0[r - 1], base.control.period_s, n_epochs)
    ref_v = reference_velocities(ref_x, base.control.period_s)
    team = _team_links(InLinks.of(base, np.arange(1, n + 1)), size, n)
    team_on = Presence.of(plan.team, src, dst, size)  # the scenario's events (issue 20)
    on_time = plan.on_time if team_on is None else plan.on_time & team_on.link_on[:-1, None, :]
    report_ok, estimate_ok = plan.report_ok, plan.estimate_ok
    ranged = RangedEpochs(plan, strategy) if plan.ranged else None
    if ranged is not None:  # these members' rows are decided epoch by epoch, from the positions
        on_time, report_ok, estimate_ok = on_time.copy(), report_ok.copy(), estimate_ok.copy()
    leader = Leader(base, HealthyRigidity(d0, edges) if detail and rigidity else None)
    log = _Log(size, n_epochs, n, d, len(edges)) if detail else None

    x = np.zeros((n_epochs + 1, size, n, d))
    x[0] = plan.x0[plan.seed_row]
    vel = np.zeros((size * n, d))
    memory = LinkMemory.empty(size * n_links, d, state_width(strategy, d))
    agent_ids = np.tile(np.arange(1, n + 1, dtype=np.int64), size)
    v_known = np.zeros((size, n, d))  # each agent's last received v_ref
    fallbacks = np.zeros(size, dtype=np.int64)
    unicycle = base.control.dynamics == "unicycle"
    th = np.zeros((n_epochs + 1, size, n)) if unicycle else None
    saturated = np.zeros((n_epochs, size, n), dtype=np.int64) if unicycle else None
    if th is not None:
        th[0] = np.stack([initial_headings(int(s), n) for s in plan.seeds.tolist()])
    robots = RobotRows.of(base)  # the agents whose body is a ROS 2 robot (docs/robots.md)
    for k in range(n_epochs + 1):
        if k == 0 or robots.reference_row is None:  # a robot is where it went (robots.step)
            # the reference agent follows the trajectory (docs/model.md §3)
            x[k, :, r - 1] = ref_x[k]
        if k == n_epochs:
            break
        xk = x[k]
        if ranged is not None:
            ranged.decide(k, xk, on_time, report_ok, estimate_ok)
            if team_on is not None:
                on_time[k] &= team_on.link_on[k][None, :]
        if team_on is not None:
            memory = team_on.restart(k, memory, v_known)
        landing = _landing(plan, ranged, k)
        if landing is not None:
            memory = _receive_late(memory, landing, x, src, team_on, k)
        arrived = on_time[k]  # (B, L)
        x_src = xk[:, src0]  # each sender's state, for the measurements and the agents
        z = xk[:, dst0] - x_src + plan.noise[plan.seed_row, k]

        # Leader: the measurements whose report reached it → tree, BLUE, rigidity.
        known = arrived & report_ok[k][:, dst0]
        with_cov = detail and k % base.estimator.covariance_every == 0  # as the leader's
        lead = leader.epochs(known, z, ref_x[k], covariances=with_cov)
        observable = lead.estimate.observable

        # Estimates reach the agents over their control links, with v_ref[k].
        got_est = estimate_ok[k] if team_on is None else estimate_ok[k] & team_on.present[k]
        v_prev = v_known.copy()
        v_known[got_est] = ref_v[k]
        has_estimate = got_est[:, dst0] & observable[:, src0]
        # Links out of the graph leave the consensus; their memory waits for their return.
        sel = None if team_on is None else team_on.rows(k)
        links_k, memory_k, (got, received, measured, estimate, with_estimate, v_before) = _take(
            sel,
            team,
            memory,
            (
                arrived.reshape(-1),
                x_src.reshape(-1, d),
                z.reshape(-1, d),
                np.nan_to_num(lead.estimate.positions[:, src0]).reshape(-1, d),
                has_estimate.reshape(-1),
                v_prev[:, dst0].reshape(-1, d),
            ),
        )
        step = agent_epoch(
            base,
            strategy,
            k,
            links_k,
            xk.reshape(size * n, d),
            vel,
            got,
            received,
            measured,
            memory_k,
            estimate,
            with_estimate,
            v_before,
            v_known.reshape(-1, d),
            headings=None if th is None else th[k].reshape(-1),
            agents=agent_ids,
        )
        memory, sub = _put(sel, memory, step)
        fallbacks += sub.fallback.reshape(size, n_links).sum(axis=1)
        if log is not None:
            log.epoch(k, lead, sub, xk, src, n_links)
        nxt, vel = step.positions.reshape(size, n, d), step.velocities
        if th is not None and saturated is not None and step.headings is not None:
            th[k + 1] = step.headings.reshape(size, n)
            th[k + 1, :, r - 1] = reference_heading(th[k, :, r - 1], ref_x[k + 1] - ref_x[k])
            assert step.saturated is not None
            saturated[k] = step.saturated.reshape(size, n)
            saturated[k, :, r - 1] = 0  # the reference agent does not steer by its command
        if team_on is not None:
            frozen = ~team_on.present[k]  # an agent out of the team stays where it is, at rest
            nxt[:, frozen] = xk[:, frozen]
            vel.reshape(size, n, d)[:, frozen] = 0.0
            if th is not None and saturated is not None:
                th[k + 1, :, frozen] = th[k, :, frozen]
                saturated[k, :, frozen] = 0
        x[k + 1] = nxt
        turned = None if th is None else (th[k], th[k + 1])
        clipped = None if saturated is None else saturated[k]
        robots.step(xk, x[k + 1], ref_x[k + 1], turned, clipped)

    result = BatchResult(
        plan=plan,
        strategy=strategy,
        positions=x,
        formation_error=formation_error(x, edges, base.weights),
        shape_error=shape_error(x, edges, d0),
        delivered=on_time,
        fallbacks=fallbacks,
        detail=detail,
        report_ok=report_ok,
        estimate_ok=estimate_ok,
        headings=th,
        saturated=saturated,
        air_drops={} if ranged is None else ranged.air_drops,
    )
    if log is not None:
        log.fill(result, d)
    return result


def _team_links(one: InLinks, size: int, n: int) -> InLinks:
    """The in-links of every agent of ``size`` members, member after member (rows ``b·n + i``)."""
    offsets = (np.arange(size, dtype=np.int64) * n)[:, None]
    return InLinks(
        index=np.tile(one.index, size),
        sender=np.tile(one.sender, size),
        receiver=np.tile(one.receiver, size),
        receiver_row=(offsets + one.receiver_row[None, :]).reshape(-1),
        desired=np.tile(one.desired, (size, 1)),
        distance_sq=np.tile(one.distance_sq, size),
    )


def _landing(plan: BatchPlan, ranged: RangedEpochs | None, k: int) -> tuple[Ints, Ints] | None:
    """The delayed packets landing at epoch ``k``, the plan's and the ranged members', or None."""
    planned = plan.late.get(k)
    extra = [] if ranged is None else ranged.landing(k)
    if not extra:
        return planned
    parts = extra if planned is None else [planned, *extra]
    return newest_late(np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]))


def _receive_late(
    memory: LinkMemory,
    late: tuple[Ints, Ints],
    x: Array,
    src: Ints,
    team_on: Presence | None,
    k: int,
) -> LinkMemory:
    """Delayed packets landing at epoch ``k``: (flat link ``b·L + l``, sent epoch) each."""
    n_links = src.size
    flat, sent = late
    if team_on is not None:
        keep = team_on.landing(k, flat, sent)
        flat, sent = flat[keep], sent[keep]
    values = np.zeros(memory.last.shape)
    values[flat] = x[sent, flat // n_links, src[flat % n_links] - 1]
    sent_full = np.zeros(memory.last_epoch.shape, dtype=np.int64)
    sent_full[flat] = sent
    mask = np.zeros(memory.last_epoch.shape, dtype=bool)
    mask[flat] = True
    return memory.receive_late(values, sent_full, mask)


def _take(
    sel: Ints | None, team: InLinks, memory: LinkMemory, per_link: tuple[npt.NDArray[Any], ...]
) -> tuple[InLinks, LinkMemory, tuple[npt.NDArray[Any], ...]]:
    """The links ``sel`` of the team, their memory and their rows of ``per_link`` (all: None)."""
    if sel is None:
        return team, memory, per_link
    return team.take(sel), memory.take(sel), tuple(a[sel] for a in per_link)


def _put(sel: Ints | None, memory: LinkMemory, step: AgentStep) -> tuple[LinkMemory, Substitution]:
    """The memory and substitution of every link after a step over the links ``sel``.

    The links left out keep their memory and substitute nothing.
    """
    if sel is None:
        return step.memory, step.substitution
    return memory.put(sel, step.memory), step.substitution.spread(sel, memory.last_epoch.size)


class _Log:
    """The leader's per-epoch outputs and the substitutions of a batch run with ``detail``."""

    def __init__(self, size: int, n_epochs: int, n: int, d: int, m: int) -> None:
        self.est = np.full((n_epochs, size, n, d), np.nan)
        self.cov = np.full((n_epochs, size, n, d, d), np.nan)
        self.obs = np.zeros((n_epochs, size, n), dtype=bool)
        self.healthy = np.zeros((n_epochs, size, m), dtype=bool)
        self.tree = np.zeros((n_epochs, size, m), dtype=bool)
        self.components = np.zeros((n_epochs, size), dtype=np.int64)
        self.rank = np.zeros((n_epochs, size), dtype=np.int64)
        self.rigid = np.full((n_epochs, size), -1, dtype=np.int64)
        self.subs: list[tuple[Ints, Ints, Ints, Array, Array, Mask]] = []

    def epoch(
        self, k: int, lead: LeaderEpochs, sub: Substitution, xk: Array, src: Ints, n_links: int
    ) -> None:
        est = lead.estimate
        self.est[k], self.obs[k] = est.positions, est.observable
        if est.covariances is not None:
            self.cov[k] = est.covariances
        self.healthy[k], self.tree[k], self.components[k] = lead.healthy, lead.tree, lead.components
        if lead.rigidity_rank is not None:
            self.rank[k] = lead.rigidity_rank
        if lead.rigid is not None:
            self.rigid[k] = lead.rigid
        # Every lost variable counts (docs/model.md §7), also those the reference agent substitutes
        # without steering by them: on the default scenario they are the only ones with error.
        idx = np.flatnonzero(sub.substituted)
        if idx.size:
            b_of, l_of = idx // n_links, idx % n_links
            error = sub.values[idx] - xk[b_of, src[l_of] - 1]
            self.subs.append(
                (b_of, np.full(idx.size, k), l_of, error, sub.values[idx], sub.fallback[idx])
            )

    def fill(self, result: BatchResult, d: int) -> None:
        result.estimates, result.estimate_cov, result.observable = self.est, self.cov, self.obs
        result.healthy, result.tree = self.healthy, self.tree
        result.components, result.rigidity_rank = self.components, self.rank
        result.rigid = self.rigid
        if not self.subs:
            result.sub_error = result.sub_value = np.zeros((0, d))
            return
        member = np.concatenate([s[0] for s in self.subs])
        order = np.argsort(member, kind="stable")  # per member: epoch-major, link order
        result.sub_member = member[order]
        result.sub_epoch = np.concatenate([s[1] for s in self.subs])[order]
        result.sub_link = np.concatenate([s[2] for s in self.subs])[order]
        result.sub_error = np.concatenate([s[3] for s in self.subs])[order]
        result.sub_value = np.concatenate([s[4] for s in self.subs])[order]
        result.sub_fallback = np.concatenate([s[5] for s in self.subs])[order]


__all__ = [
    "VARIANT_FIELDS",
    "BatchPlan",
    "BatchResult",
    "plan_batch",
    "run_batch",
]
