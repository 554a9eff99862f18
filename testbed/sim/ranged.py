"""The simulator's links that decide by their length, decided epoch by epoch (docs/model.md §8).

A distance model (``range``, ``logistic``, ``log_distance``) decides link ``i → j`` of epoch
``k`` by ``||x_i[k] − x_j[k]||`` (a control link's leader end is the scenario's access point),
which the simulator knows only once it has computed epoch ``k``. The members' draws come from
:func:`netem.links.matrix.delivery_plan` in the plan; here they meet the lengths, measured with
:func:`netem.links.matrix.link_lengths` as netem measures them, so both give the same verdicts.
A member with capacity queues then passes what the models passed through them, an epoch at a
time (:class:`netem.CapacityPlanner`), and a member with a shared air puts what they passed on
it (:class:`netem.AirPlanner`: the epoch's positions decide), as netem's lockstep does; the
run's strategy says whether the estimation traffic takes it (``network.air.estimation_traffic``).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from formation.keys import LEADER_ENDPOINT
from netem import AirPlanner, CapacityPlanner, air_of, link_lengths
from testbed.sim.plan import BatchPlan, offered

Array = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]
Ints = npt.NDArray[np.int64]


class RangedEpochs:
    """Epoch ``k``'s decisions of the plan's ranged members, written into the batch's arrays."""

    def __init__(self, plan: BatchPlan, strategy: str) -> None:
        base = plan.base
        self.members = sorted(plan.ranged)
        self.decisions = [plan.ranged[b].decisions for b in self.members]
        self.n, self.n_links = base.n, len(base.directed_links)
        links = base.directed_links
        agents = np.arange(self.n)
        self.src = np.concatenate([links[:, 0] - 1, agents])  # rows measured from the agents
        self.dst = np.concatenate([links[:, 1] - 1, agents])
        d = base.dimension
        ap = [plan.ranged[b].access_point for b in self.members]
        # (M, d) each member's access point; NaN where no control link decides by length
        self.access_point = np.stack([np.full(d, np.nan) if a is None else a for a in ap])
        self.late: dict[int, list[tuple[Ints, Ints]]] = {}  # arrival epoch → (flat link, sent)
        control = [(i, LEADER_ENDPOINT) for i in range(1, self.n + 1)]
        control += [(LEADER_ENDPOINT, i) for i in range(1, self.n + 1)]
        every = np.concatenate([links, np.array(control, dtype=np.int64)])
        self.queues = [  # fresh per run: a planner's queues carry their backlog
            CapacityPlanner(plan.scenarios[b], every)
            if plan.scenarios[b].network.capacity
            else None
            for b in self.members
        ]
        self.air = [
            None
            if (net := air_of(plan.scenarios[b], int(plan.seeds[b]), strategy)) is None
            else AirPlanner(net, every)
            for b in self.members
        ]
        # member → (epoch, column, cause code) of each packet the air dropped
        self.air_drops: dict[int, list[tuple[int, int, int]]] = {b: [] for b in self.members}
        self.present = None if plan.team is None else plan.team.present
        self.links = links

    def decide(self, k: int, xk: Array, on_time: Mask, report_ok: Mask, estimate_ok: Mask) -> None:
        """Decide epoch ``k`` from ``xk`` (B, n, d) [m]; fills row ``k`` of ``on_time`` (E, B, L),
        ``report_ok``, ``estimate_ok`` (E, B, n) for the ranged members, and their late packets."""
        n, n_links = self.n, self.n_links
        x = xk[self.members]  # (M, n, d)
        formation = link_lengths(x[:, self.src[:n_links]], x[:, self.dst[:n_links]])  # (M, L)
        control = link_lengths(x, self.access_point[:, None, :])  # (M, n): agent ↔ access point
        lengths = np.concatenate([formation, control, control], axis=1)
        for row, (b, decisions) in enumerate(zip(self.members, self.decisions, strict=True)):
            delivered, _, delay = decisions.at(k, lengths[row])
            queues, air = self.queues[row], self.air[row]
            present = None if self.present is None else self.present[k : k + 1]
            if queues is not None:  # the queues see what the models passed, delayed or not
                seen = offered(delivered[None], present, self.links, n)[0]
                delivered = delivered & (queues.epoch(k, seen) == 0)
            if air is not None:  # what they passed takes the air
                causes = air.epoch(k, x[row], offered(delivered[None], present, self.links, n)[0])
                self.air_drops[b] += [(k, int(c), int(causes[c])) for c in np.flatnonzero(causes)]
                delivered = delivered & (causes == 0)
            ok = delivered & (delay == 0)
            on_time[k, b] = ok[:n_links]
            report_ok[k, b] = ok[n_links : n_links + n]
            estimate_ok[k, b] = ok[n_links + n :]
            link = np.flatnonzero(delivered[:n_links] & (delay[:n_links] > 0))
            for arrival in np.unique(k + delay[link]).tolist():
                sel = link[k + delay[link] == arrival]
                self.late.setdefault(int(arrival), []).append(
                    (b * n_links + sel, np.full(sel.size, k, dtype=np.int64))
                )

    def landing(self, k: int) -> list[tuple[Ints, Ints]]:
        """The delayed packets of the ranged members landing at epoch ``k`` (flat link, sent)."""
        return self.late.pop(k, [])


__all__ = ["RangedEpochs"]
