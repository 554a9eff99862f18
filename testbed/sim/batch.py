"""The batch simulator: many seeds (and network variants) of one scenario at once, in one process.

:func:`simulate` (``testbed.sim.simulate``) runs one seed epoch by epoch; a sweep needs thousands of
runs. Here the members of a batch (``B`` pairs of a network variant and a seed, all sharing the
team, graph, controller, reference, noise and estimator) advance together: agents and links of
every member are flattened into the batch dimension of the agent core
(:func:`agent.epoch.agent_epoch`, vectorised over any set of links), the links' decisions come
from netem's :func:`netem.models.delivery_matrix`, the measurement noise from
:func:`agent.measurement.measurement_noise` (same keys), and the leader (docs/model.md §4–§5) runs
batched (``testbed.sim.batch_leader``):

* **Kruskal** over a fixed edge order ``(w, lo, hi, index)`` (the order of
  ``leader.mst``): the forest is the unique greedy one, so a component-label sweep over the
  ``m`` edges, vectorised across members, keeps exactly the edges union-find keeps.
* **BLUE** (docs/model.md §5) with one ``P`` for every edge: fusing the one or two measurements of an
  edge (``c_e`` of them, mean value, covariance ``P / c_e``) gives ``A = L_c ⊗ P⁻¹`` with
  ``L_c`` the grounded Laplacian weighted by ``c_e``, so ``x̂_b − x_r = L_c⁻¹ Σ_e c_e h_e ȳ_eᵀ``
  and ``Cov(x̂_v) = (L_c⁻¹)_vv P`` whatever ``P`` is. A batched dense solve over
  ``(B, n − 1, n − 1)``: on a tree it equals the path sum of ``leader.blue``, on all healthy
  edges the sparse solve, to rounding.

The results equal :func:`testbed.sim.simulate.simulate` member by member to rounding (tests hold
them to 1e-9). Cost: the noise, the schedules and the initial positions do not depend on the
strategy, so a :class:`BatchPlan` is built once and run for every strategy.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from agent.epoch import InLinks, agent_epoch
from agent.measurement import measurement_noise
from agent.strategies import LinkMemory
from formation.errors import TestbedError
from formation.reference import reference_positions, reference_velocities
from formation.scenario import LEADER_ENDPOINT, Scenario, StrategyName
from leader.rigidity import healthy_rigidity
from netem.models import delivery_matrix
from recorder.metrics import formation_error, nees, shape_error
from testbed.sim.batch_leader import batch_blue, batch_forest, kruskal_order
from testbed.sim.simulate import SimResult

Array = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]
Ints = npt.NDArray[np.int64]

# Fields members of one batch may differ in: the rest is the shared structure.
VARIANT_FIELDS = ("name", "description", "seed", "epochs", "network", "runtime", "recording")


class BatchError(TestbedError):
    """Members that cannot share a batch; names the member and the differing field."""


@dataclass(frozen=True)
class BatchPlan:
    """The strategy-independent inputs of a batch of ``B`` members over ``E`` epochs.

    base : the shared structure (first member's scenario)
    scenarios : (B,) each member's scenario (its network); seeds : (B,) each member's seed
    on_time : (E, B, L) formation link delivered with no delay
    late : arrival epoch → (flat link index ``b·L + l``, sent epoch) of delayed deliveries
    report_ok, estimate_ok : (E, B, n) control links delivered in time
    noise : (S, E, L, d) measurement noise of the distinct seeds [m]; seed_row : (B,) row per member
    x0 : (S, n, d) initial positions of the distinct seeds [m]
    active : (E + 1, n) agents taking part at each epoch (None: all, always)
    """

    base: Scenario
    scenarios: tuple[Scenario, ...]
    seeds: Ints
    epochs: int
    on_time: Mask
    late: dict[int, tuple[Ints, Ints]]
    report_ok: Mask
    estimate_ok: Mask
    noise: Array
    seed_row: Ints
    x0: Array
    active: Mask | None = None

    @property
    def size(self) -> int:
        return int(self.seeds.shape[0])

    def subset(self, members: Sequence[int]) -> BatchPlan:
        """The plan of some members only (e.g. those a resumed sweep still has to run)."""
        idx = np.asarray(members, dtype=np.int64)
        n_links = self.on_time.shape[2]
        late: dict[int, tuple[Ints, Ints]] = {}
        new_row = np.full(self.size, -1, dtype=np.int64)
        new_row[idx] = np.arange(idx.size)
        for k, (flat, sent) in self.late.items():
            b, link = flat // n_links, flat % n_links
            keep = new_row[b] >= 0
            if keep.any():
                late[k] = (new_row[b[keep]] * n_links + link[keep], sent[keep])
        return replace(
            self,
            scenarios=tuple(self.scenarios[i] for i in idx.tolist()),
            seeds=self.seeds[idx],
            on_time=self.on_time[:, idx],
            late=late,
            report_ok=self.report_ok[:, idx],
            estimate_ok=self.estimate_ok[:, idx],
            seed_row=self.seed_row[idx],
        )


def _structure(s: Scenario) -> dict[str, Any]:
    data = s.model_dump()
    for key in VARIANT_FIELDS:
        data.pop(key, None)
    return data


def plan_batch(
    scenarios: Scenario | Sequence[Scenario],
    seeds: Sequence[int],
    epochs: int | None = None,
    active: npt.ArrayLike | None = None,
) -> BatchPlan:
    """Draw everything a batch needs that no strategy changes.

    Parameters
    ----------
    scenarios : one scenario for every member, or a sequence of ``B`` variants that differ only
        in ``VARIANT_FIELDS`` (e.g. the network: one loss rate each)
    seeds : (B,) the members' seeds
    epochs : number of epochs (default: the first scenario's)
    active : (E + 1, n) bool, optional; agents taking part at each epoch (dynamic formations,
        in-process only): links of an inactive agent carry nothing and leave the consensus,
        the leader's graph and the estimate; an inactive agent stays where it is.
    """
    seed_arr = np.asarray(seeds, dtype=np.int64).reshape(-1)
    if isinstance(scenarios, Scenario):
        members: tuple[Scenario, ...] = (scenarios,) * seed_arr.size
    else:
        members = tuple(scenarios)
    if len(members) != seed_arr.size or not members:
        raise BatchError(
            f"{len(members)} scenarios for {seed_arr.size} seeds; expected one each (≥ 1)"
        )
    base = members[0]
    n_epochs = base.epochs if epochs is None else int(epochs)
    shared = _structure(base)
    checked = {id(base)}
    for b, s in enumerate(members):
        if id(s) in checked:
            continue
        checked.add(id(s))
        if _structure(s) != shared:
            diff = sorted(k for k, v in _structure(s).items() if shared.get(k) != v)
            raise BatchError(
                f"member {b} ({s.name}) differs from member 0 in {', '.join(diff)}; "
                f"members may differ only in {', '.join(VARIANT_FIELDS)}"
            )
    n, d = base.n, base.dimension
    links = base.directed_links
    n_links = len(links)
    ctl_links = np.array(
        [(i, LEADER_ENDPOINT) for i in range(1, n + 1)]
        + [(LEADER_ENDPOINT, i) for i in range(1, n + 1)],
        dtype=np.int64,
    )
    all_links = np.concatenate([links, ctl_links])
    size = seed_arr.size
    on_time = np.zeros((n_epochs, size, n_links), dtype=bool)
    report_ok = np.zeros((n_epochs, size, n), dtype=bool)
    estimate_ok = np.zeros((n_epochs, size, n), dtype=bool)
    late_k: list[Ints] = []
    late_flat: list[Ints] = []
    late_sent: list[Ints] = []
    stacks: dict[str, list[Any]] = {}
    net_of: dict[int, str] = {}
    cache: dict[tuple[str, int], tuple[Mask, Ints, Mask]] = {}
    for b, (s, seed) in enumerate(zip(members, seed_arr.tolist(), strict=True)):
        if id(s) not in net_of:
            net_of[id(s)] = s.network.model_dump_json()
        net = net_of[id(s)]
        if net not in stacks:
            stacks[net] = (
                [s.formation_link_models(int(a), int(c)) for a, c in links]
                + [s.control_link_models(i, "report") for i in range(1, n + 1)]
                + [s.control_link_models(i, "estimate") for i in range(1, n + 1)]
            )
        key = (net, seed)
        if key not in cache:
            mat = delivery_matrix(stacks[net], seed, all_links, n_epochs)
            ok = mat.delivered & (mat.delay_epochs == 0)
            cache[key] = (mat.delivered[:, :n_links], mat.delay_epochs[:, :n_links], ok)
        delivered, delay, ok = cache[key]
        on_time[:, b] = ok[:, :n_links]
        report_ok[:, b] = ok[:, n_links : n_links + n]
        estimate_ok[:, b] = ok[:, n_links + n :]
        k_sent, link = np.nonzero(delivered & (delay > 0))
        if k_sent.size:
            late_k.append(k_sent + delay[k_sent, link])
            late_flat.append(b * n_links + link)
            late_sent.append(k_sent)
    late: dict[int, tuple[Ints, Ints]] = {}
    if late_k:
        ks, flat, sent = (
            np.concatenate(late_k),
            np.concatenate(late_flat),
            np.concatenate(late_sent),
        )
        for k in np.unique(ks).tolist():
            sel = ks == k
            # several packets of one link landing at once: the newest one is what memory keeps
            f, s_ep = flat[sel], sent[sel]
            order = np.lexsort((s_ep, f))
            last = np.r_[f[order][1:] != f[order][:-1], True]
            late[int(k)] = (f[order][last], s_ep[order][last])

    distinct, seed_row = np.unique(seed_arr, return_inverse=True)
    src, dst = links[:, 0], links[:, 1]
    epochs_col = np.arange(n_epochs)[:, None]
    cov = base.noise_covariance
    noise = (
        np.stack(
            [
                measurement_noise(cov, int(s), dst[None, :], src[None, :], epochs_col)
                for s in distinct.tolist()
            ]
        )
        if n_links
        else np.zeros((distinct.size, n_epochs, 0, d))
    )
    x0 = np.stack([base.initial_positions(int(s)) for s in distinct.tolist()])
    act = None
    if active is not None:
        act = np.asarray(active, dtype=bool)
        if act.shape != (n_epochs + 1, n):
            raise BatchError(f"active has shape {act.shape}; expected ({n_epochs + 1}, {n})")
        if not act[:, base.leader - 1].all():
            raise BatchError(
                f"active: the reference agent {base.leader} must take part in every epoch"
            )
    return BatchPlan(
        base=base,
        scenarios=members,
        seeds=seed_arr,
        epochs=n_epochs,
        on_time=on_time,
        late=late,
        report_ok=report_ok,
        estimate_ok=estimate_ok,
        noise=noise,
        seed_row=seed_row.astype(np.int64),
        x0=x0,
        active=act,
    )


@dataclass
class BatchResult:
    """What a batch produced; axis ``B`` is the member, row ``i − 1`` of ``n`` is agent ``i``.

    positions : (E + 1, B, n, d) true positions [m]; formation_error, shape_error : (E + 1, B) [m]
    delivered : (E, B, L) formation link delivered in time
    With ``detail``: estimates (E, B, n, d) (NaN where unobservable), estimate_cov
    (E, B, n, d, d), observable (E, B, n), healthy and tree (E, B, m), components and
    rigidity_rank (E, B), and every substitution as (member, epoch, link, error (N, d)).
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
    sub_member: Ints = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    sub_epoch: Ints = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    sub_link: Ints = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    sub_error: Array = field(default_factory=lambda: np.zeros((0, 0)))

    @property
    def size(self) -> int:
        return self.plan.size

    def member(self, b: int) -> SimResult:
        """Member ``b`` as the one-seed simulator's :class:`SimResult` (needs ``detail``)."""
        if not self.detail:
            raise BatchError("member(): the batch ran without detail; run it with detail=True")
        assert self.estimates is not None and self.estimate_cov is not None
        assert self.observable is not None and self.healthy is not None and self.tree is not None
        assert self.components is not None and self.rigidity_rank is not None
        plan = self.plan
        base = plan.base
        d, r = base.dimension, base.leader
        est, cov, obs = self.estimates[:, b], self.estimate_cov[:, b], self.observable[:, b]
        x = self.positions[:, b]
        scored = obs & (np.arange(base.n) != r - 1)[None, :]
        nees_vals: list[Array] = []
        est_err: list[Array] = []
        for k in np.flatnonzero(scored.any(axis=1)).tolist():
            nees_vals.append(nees(est[k], cov[k], x[k], scored[k]))
            est_err.append(est[k][scored[k]] - x[k][scored[k]])
        sel = self.sub_member == b
        return SimResult(
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
            report_ok=plan.report_ok[:, b],
            estimate_ok=plan.estimate_ok[:, b],
            healthy=self.healthy[:, b],
            tree=self.tree[:, b],
            components=self.components[:, b],
            rigidity_rank=self.rigidity_rank[:, b],
            substitution_errors=self.sub_error[sel] if sel.any() else np.zeros((0, d)),
            substitution_epochs=self.sub_epoch[sel],
            fallbacks=int(self.fallbacks[b]),
            nees_values=np.concatenate(nees_vals) if nees_vals else np.zeros(0),
            estimation_errors=np.concatenate(est_err) if est_err else np.zeros((0, d)),
        )


def run_batch(
    plan: BatchPlan, strategy: StrategyName, *, detail: bool = True, rigidity: bool = True
) -> BatchResult:
    """Run every member of ``plan`` with ``strategy``; mirrors ``testbed.sim.simulate`` step by step.

    ``detail`` keeps the leader's per-epoch outputs and the substitutions (``member()`` needs it);
    ``rigidity`` adds the rigidity rank of each healthy subgraph (cached per pattern).
    """
    base = plan.base
    size, n_epochs = plan.size, plan.epochs
    n, d, r = base.n, base.dimension, base.leader
    edges, weights, d0 = base.edge_array, base.weights, base.offsets
    links = base.directed_links
    m, n_links = len(edges), len(links)
    src, dst = links[:, 0], links[:, 1]
    period = base.control.period_s
    cov = base.noise_covariance
    order = kruskal_order(base)
    both = base.estimator.edge_rule == "both"
    use_tree = base.estimator.edges == "tree"

    one = InLinks.of(base, np.arange(1, n + 1))
    offsets = (np.arange(size, dtype=np.int64) * n)[:, None]
    flat_links = InLinks(
        index=np.tile(one.index, size),
        sender=np.tile(one.sender, size),
        receiver=np.tile(one.receiver, size),
        receiver_row=(offsets + one.receiver_row[None, :]).reshape(-1),
        desired=np.tile(one.desired, (size, 1)),
        distance_sq=np.tile(one.distance_sq, size),
    )
    ref_x = reference_positions(base.reference, d0[r - 1], period, n_epochs)
    ref_v = reference_velocities(ref_x, period)

    act = plan.active
    link_act = None
    if act is not None:
        link_act = act[:, src - 1] & act[:, dst - 1]  # (E + 1, L)

    x = np.zeros((n_epochs + 1, size, n, d))
    x[0] = plan.x0[plan.seed_row]
    x[0, :, r - 1] = ref_x[0]
    vel = np.zeros((size * n, d))
    memory = LinkMemory.empty(size * n_links, d)
    v_known = np.zeros((size, n, d))
    on_time = plan.on_time if link_act is None else plan.on_time & link_act[:-1, None, :]
    fallbacks = np.zeros(size, dtype=np.int64)

    if detail:
        est_all = np.full((n_epochs, size, n, d), np.nan)
        cov_all = np.full((n_epochs, size, n, d, d), np.nan)
        obs_all = np.zeros((n_epochs, size, n), dtype=bool)
        healthy_all = np.zeros((n_epochs, size, m), dtype=bool)
        tree_all = np.zeros((n_epochs, size, m), dtype=bool)
        comp_all = np.zeros((n_epochs, size), dtype=np.int64)
        rank_all = np.zeros((n_epochs, size), dtype=np.int64)
    rank_cache: dict[bytes, int] = {}
    subs: list[tuple[Ints, Ints, Ints, Array]] = []

    for k in range(n_epochs):
        xk = x[k]
        if k in plan.late:
            flat, sent = plan.late[k]
            if link_act is not None:
                keep = link_act[k, flat % n_links]
                flat, sent = flat[keep], sent[keep]
            values = np.zeros((size * n_links, d))
            b_of, l_of = flat // n_links, flat % n_links
            values[flat] = x[sent, b_of, src[l_of] - 1]
            sent_full = np.zeros(size * n_links, dtype=np.int64)
            sent_full[flat] = sent
            mask = np.zeros(size * n_links, dtype=bool)
            mask[flat] = True
            memory = memory.receive_late(values, sent_full, mask)
        arrived = on_time[k]  # (B, L)
        z = xk[:, dst - 1] - xk[:, src - 1] + plan.noise[plan.seed_row, k]

        # Leader: reported measurements → healthy edges → Kruskal forest → BLUE.
        known = arrived & plan.report_ok[k][:, dst - 1]
        per_edge = known.reshape(size, m, 2)
        healthy = per_edge.all(axis=2) if both else per_edge.any(axis=2)
        tree, labels = batch_forest(n, edges, order, healthy)
        use_edge = tree if use_tree else healthy
        used = per_edge & use_edge[:, :, None]
        counts = used.sum(axis=2)
        # link 2e is lo → hi (z = x_hi − x_lo), 2e + 1 is hi → lo (z = x_lo − x_hi)
        zz = z.reshape(size, m, 2, d)
        oriented = np.where(used[:, :, 1, None], zz[:, :, 1], 0.0) - np.where(
            used[:, :, 0, None], zz[:, :, 0], 0.0
        )
        fused = oriented / np.maximum(counts, 1)[:, :, None]
        observable = labels == labels[:, r - 1 : r]
        est, est_cov = batch_blue(n, edges, counts, fused, observable, r, ref_x[k], cov, detail)
        if detail:
            assert est_cov is not None
            est_all[k], cov_all[k], obs_all[k] = est, est_cov, observable
            healthy_all[k], tree_all[k] = healthy, tree
            comp_all[k] = n - tree.sum(axis=1)
            if rigidity:
                for b in range(size):
                    key = healthy[b].tobytes()
                    if key not in rank_cache:
                        rank_cache[key] = healthy_rigidity(d0, edges, healthy[b])[0]
                    rank_all[k, b] = rank_cache[key]

        # Estimates (with v_ref[k]) reach the agents over their control links.
        got_est = plan.estimate_ok[k]
        if act is not None:
            got_est = got_est & act[k][None, :]
        v_prev = v_known.copy()
        v_known[got_est] = ref_v[k]
        has_estimate = got_est[:, dst - 1] & observable[:, src - 1]
        x_flat = xk.reshape(size * n, d)
        received = xk[:, src - 1].reshape(-1, d)
        estimate = np.nan_to_num(est[:, src - 1]).reshape(-1, d)
        v_prev_links = v_prev[:, dst - 1].reshape(-1, d)
        if link_act is None or link_act[k].all():
            step = agent_epoch(
                base,
                strategy,
                k,
                flat_links,
                x_flat,
                vel,
                arrived.reshape(-1),
                received,
                z.reshape(-1, d),
                memory,
                estimate,
                has_estimate.reshape(-1),
                v_prev_links,
                v_known.reshape(-1, d),
            )
            memory, sub = step.memory, step.substitution
            sub_idx = np.flatnonzero(sub.substituted)
            sub_values = sub.values[sub_idx]
            sub_fallback = sub.fallback
        else:
            sel = np.flatnonzero(np.tile(link_act[k], size))
            part = InLinks(
                *(
                    getattr(flat_links, f)[sel]
                    for f in (
                        "index",
                        "sender",
                        "receiver",
                        "receiver_row",
                        "desired",
                        "distance_sq",
                    )
                )
            )
            mem_part = LinkMemory(
                memory.last[sel], memory.last_epoch[sel], memory.blend[sel], memory.has_blend[sel]
            )
            step = agent_epoch(
                base,
                strategy,
                k,
                part,
                x_flat,
                vel,
                arrived.reshape(-1)[sel],
                received[sel],
                z.reshape(-1, d)[sel],
                mem_part,
                estimate[sel],
                has_estimate.reshape(-1)[sel],
                v_prev_links[sel],
                v_known.reshape(-1, d),
            )
            new = step.memory
            memory = LinkMemory(
                _scatter(memory.last, sel, new.last),
                _scatter(memory.last_epoch, sel, new.last_epoch),
                _scatter(memory.blend, sel, new.blend),
                _scatter(memory.has_blend, sel, new.has_blend),
            )
            sub = step.substitution
            sub_idx = sel[sub.substituted]
            sub_values = sub.values[sub.substituted]
            sub_fallback = np.zeros(size * n_links, dtype=bool)
            sub_fallback[sel] = sub.fallback
        fallbacks += sub_fallback.reshape(size, n_links).sum(axis=1)
        if detail and sub_idx.size:
            b_of, l_of = sub_idx // n_links, sub_idx % n_links
            subs.append(
                (b_of, np.full(sub_idx.size, k), l_of, sub_values - xk[b_of, src[l_of] - 1])
            )
        nxt = step.positions.reshape(size, n, d)
        vel = step.velocities
        if act is not None:
            frozen = ~act[k]  # an agent out of the formation stays where it is
            nxt[:, frozen] = xk[:, frozen]
            vel.reshape(size, n, d)[:, frozen] = 0.0
        nxt[:, r - 1] = ref_x[k + 1]
        x[k + 1] = nxt

    result = BatchResult(
        plan=plan,
        strategy=strategy,
        positions=x,
        formation_error=formation_error(x, edges, weights),
        shape_error=shape_error(x, edges, d0),
        delivered=on_time,
        fallbacks=fallbacks,
        detail=detail,
    )
    if detail:
        result.estimates, result.estimate_cov, result.observable = est_all, cov_all, obs_all
        result.healthy, result.tree = healthy_all, tree_all
        result.components, result.rigidity_rank = comp_all, rank_all
        if subs:
            mem_b = np.concatenate([s[0] for s in subs])
            order_b = np.argsort(mem_b, kind="stable")  # per member: epoch-major, link order
            result.sub_member = mem_b[order_b]
            result.sub_epoch = np.concatenate([s[1] for s in subs])[order_b]
            result.sub_link = np.concatenate([s[2] for s in subs])[order_b]
            result.sub_error = np.concatenate([s[3] for s in subs])[order_b]
        else:
            result.sub_error = np.zeros((0, d))
    return result


def _scatter(full: npt.NDArray[Any], sel: Ints, part: npt.NDArray[Any]) -> npt.NDArray[Any]:
    out = full.copy()
    out[sel] = part
    return out


def simulate_batch(
    scenario: Scenario,
    strategy: StrategyName | None = None,
    seeds: Sequence[int] = (0,),
    epochs: int | None = None,
    *,
    detail: bool = True,
) -> BatchResult:
    """Every seed of ``seeds`` of one scenario at once (``simulate`` for many seeds)."""
    plan = plan_batch(scenario, seeds, epochs)
    return run_batch(plan, strategy or scenario.strategy.name, detail=detail)


__all__ = [
    "BatchError",
    "BatchPlan",
    "BatchResult",
    "plan_batch",
    "run_batch",
    "simulate_batch",
]
