"""What a batch of runs needs that no strategy changes (docs/model.md §3–§5, §8).

The members of a batch (``B`` pairs of a network variant and a seed, sharing the team, graph,
controller, reference, noise and estimator) draw their links' decisions from netem's
:func:`netem.links.matrix.delivery_plan`, their measurement noise from
:func:`agent.measurement.measurement_noise` (the keys an agent process uses) and their initial
positions from the scenario, once: :func:`testbed.sim.batch.run_batch` runs the plan for every
strategy. A member with a distance model (``range``, ``logistic``, ``log_distance``) keeps its
:class:`netem.links.matrix.DeliveryPlan`: the epoch loop decides those links from the positions it
computes (:class:`RangedMember`), with the same draws netem uses.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from agent import measurement_noise
from formation.errors import BatchError
from formation.events import Membership, membership
from formation.keys import LEADER_ENDPOINT
from formation.linkmodels import LinkModelSpec
from formation.scenario import Scenario
from netem import DeliveryPlan, capacity_plan, delivery_plan

Mask = npt.NDArray[np.bool_]
Ints = npt.NDArray[np.int64]
Array = npt.NDArray[np.float64]

NOISE_DRAWS = 1 << 20  # noise draws per block of epochs (plan_batch)

# Fields members of one batch may differ in: the rest is the shared structure.
VARIANT_FIELDS = ("name", "description", "seed", "epochs", "network", "runtime", "recording")


@dataclass(frozen=True)
class RangedMember:
    """A member whose links decide by their length: its decisions and its access point.

    decisions : over every link of ``plan_batch``'s order (formation links, reports, estimates)
    access_point : (d,) control links' leader end [m] (None: no control link has a distance model)
    """

    decisions: DeliveryPlan
    access_point: Array | None


def newest_late(flat: Ints, sent: Ints) -> tuple[Ints, Ints]:
    """Delayed packets landing at one epoch, one per link: the newest is what memory keeps.

    flat : (P,) flat link ``b·L + l`` of each packet; sent : (P,) its sent epoch.
    """
    order = np.lexsort((sent, flat))
    last = np.r_[flat[order][1:] != flat[order][:-1], True]
    return flat[order][last], sent[order][last]


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
    team : who takes part at each epoch, from the scenario's events (None: all, always)
    ranged : member → its distance-model decisions; for these members ``on_time``,
        ``report_ok``, ``estimate_ok`` and ``late`` are decided by the epoch loop, not here
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
    team: Membership | None = None
    ranged: dict[int, RangedMember] = field(default_factory=dict)

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
            ranged={int(new_row[b]): m for b, m in self.ranged.items() if new_row[b] >= 0},
        )


def offered(passed: Mask, present: Mask | None, links: Ints, n: int) -> Mask:
    """(E, L + 2n) the packets the queues see (``passed``, ``present`` (E, n)): passed by the
    models, between agents taking part (netem's lockstep neither sends nor routes the others: issue 20's events)."""
    if present is None:
        return passed
    on = np.concatenate(
        [present[:, links[:, 0] - 1] & present[:, links[:, 1] - 1], present, present], axis=1
    )
    return np.asarray(passed & on, dtype=np.bool_)


def _noise(
    cov: Array, seeds: Ints, src: Ints, dst: Ints, n_epochs: int, draws: int = NOISE_DRAWS
) -> Array:
    """(S, E, L, d) every link's measurement noise for each seed [m], a block of epochs at a time.

    The draws are keyed, so a block gets the numbers the whole run gets; the hash's
    temporaries stay a few megabytes (``draws`` numbers) instead of the size of the run.
    """
    out = np.zeros((seeds.size, n_epochs, src.size, cov.shape[0]))
    if not src.size:
        return out
    step = max(1, draws // (src.size * cov.shape[0]))
    for row, seed in enumerate(seeds.tolist()):
        for k in range(0, n_epochs, step):
            epochs = np.arange(k, min(k + step, n_epochs))[:, None]
            out[row, k : k + step] = measurement_noise(
                cov, seed, dst[None, :], src[None, :], epochs
            )
    return out


def _structure(s: Scenario) -> dict[str, Any]:
    data = s.model_dump()
    for key in VARIANT_FIELDS:
        data.pop(key, None)
    return data


def _link_stacks(s: Scenario, links: Ints) -> list[tuple[LinkModelSpec, ...]]:
    """Every link's model stack in the plan's order: formation links, reports, estimates.

    Only the links an entry of ``network`` names are looked up; the others share the
    default stack (the same object the lookup returns), so a team of thousands costs
    one pass over the entries, not one per link.
    """
    named = {tuple(link.between) for link in s.network.links}
    named |= {(b, a) for a, b in named}
    formation = (
        [
            s.formation_link_models(a, c) if (a, c) in named else s.network.formation_default
            for a, c in links.tolist()
        ]
        if named
        else [s.network.formation_default] * len(links)
    )
    agents = {link.agent for link in s.network.control}
    control = [
        s.control_link_models(i, kind) if i in agents else s.network.control_default
        for kind in ("report", "estimate")
        for i in range(1, s.n + 1)
    ]
    return formation + control


def plan_batch(
    scenarios: Scenario | Sequence[Scenario],
    seeds: Sequence[int],
    epochs: int | None = None,
) -> BatchPlan:
    """Draw everything a batch needs that no strategy changes.

    Parameters
    ----------
    scenarios : one scenario for every member, or a sequence of ``B`` variants that differ only
        in ``VARIANT_FIELDS`` (e.g. the network: one loss rate each)
    seeds : (B,) the members' seeds
    epochs : number of epochs (default: the first scenario's)

    Notes
    -----
    The members share the scenario's events (``formation.events``): who takes part at each
    epoch is the plan's ``team`` (events past ``epochs`` are left out).
    """
    seed_arr = np.asarray(seeds, dtype=np.int64).reshape(-1)
    if isinstance(scenarios, Scenario):
        members: tuple[Scenario, ...] = (scenarios,) * seed_arr.size
    else:
        members = tuple(scenarios)
    if len(members) != seed_arr.size or not members:
        raise BatchError(
            f"{len(members)} scenarios for {seed_arr.size} seeds", "expected one each (≥ 1)"
        )
    base = members[0]
    n_epochs = base.epochs if epochs is None else int(epochs)
    shared: dict[str, Any] | None = None  # dumped only when a member is another object
    checked = {id(base)}
    for b, s in enumerate(members):
        if id(s) in checked:
            continue
        checked.add(id(s))
        shared = _structure(base) if shared is None else shared
        if _structure(s) != shared:
            diff = sorted(k for k, v in _structure(s).items() if shared.get(k) != v)
            raise BatchError(
                f"member {b} ({s.name})",
                f"differs from member 0 in {', '.join(diff)}; "
                f"members may differ only in {', '.join(VARIANT_FIELDS)}",
            )
    n = base.n
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
    team_k = membership(n, n_epochs, base.events).present[:n_epochs] if base.events else None
    late_k: list[Ints] = []
    late_flat: list[Ints] = []
    late_sent: list[Ints] = []
    stacks: dict[str, list[Any]] = {}
    net_of: dict[int, str] = {}
    cache: dict[tuple[str, int], tuple[Mask, Ints, Mask, DeliveryPlan | None]] = {}
    ranged: dict[int, RangedMember] = {}
    for b, (s, seed) in enumerate(zip(members, seed_arr.tolist(), strict=True)):
        if id(s) not in net_of:
            net_of[id(s)] = s.network.model_dump_json()
        net = net_of[id(s)]
        if net not in stacks:
            stacks[net] = _link_stacks(s, links)
        key = (net, seed)
        if key not in cache:
            decided = delivery_plan(stacks[net], seed, all_links, n_epochs)
            mat = decided.base
            ok = mat.delivered & (mat.delay_epochs == 0)
            delivered_all = mat.delivered
            # decided from the positions, epoch by epoch (testbed.sim.ranged): distance models
            # and the shared air
            by_position = decided.ranged or s.network.air is not None
            if s.network.capacity and not by_position:  # the queues see what the models
                # passed, delayed or not; a ranged member's, epoch by epoch
                seen = offered(mat.delivered, team_k, links, n)
                delivered_all = mat.delivered & (capacity_plan(s, seen, all_links) == 0)
                ok = ok & delivered_all
            cache[key] = (
                delivered_all[:, :n_links],
                mat.delay_epochs[:, :n_links],
                ok,
                decided if by_position else None,
            )
        delivered, delay, ok, by_length = cache[key]
        on_time[:, b] = ok[:, :n_links]
        report_ok[:, b] = ok[:, n_links : n_links + n]
        estimate_ok[:, b] = ok[:, n_links + n :]
        if by_length is not None:
            ap = s.network.access_point
            ranged[b] = RangedMember(by_length, None if ap is None else np.asarray(ap, float))
            continue  # its decisions and late packets come epoch by epoch
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
            late[int(k)] = newest_late(flat[sel], sent[sel])

    distinct, seed_row = np.unique(seed_arr, return_inverse=True)
    src, dst = links[:, 0], links[:, 1]
    noise = _noise(base.noise_covariance, distinct, src, dst, n_epochs)
    x0 = np.stack([base.initial_positions(int(s)) for s in distinct.tolist()])
    team = membership(n, n_epochs, base.events) if base.events else None
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
        team=None if team is None or team.everyone else team,
        ranged=ranged,
    )


__all__ = ["VARIANT_FIELDS", "BatchPlan", "RangedMember", "newest_late", "plan_batch"]
