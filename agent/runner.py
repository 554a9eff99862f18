"""The epoch-by-epoch state of a set of agents (one, or a pool), with no network.

The node feeds it what arrived; it runs the same :func:`agent.epoch.agent_epoch`
the simulator runs, on these agents and their in-links at once.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from agent.control import body_velocity, reference_heading
from agent.epoch import InLinks, agent_epoch
from agent.measurement import NoiseKeys, relative_measurement
from agent.strategies import LinkMemory, state_width
from formation.reference import reference_positions
from formation.robots import initial_headings
from formation.scenario import Scenario, StrategyName

Array = npt.NDArray[np.float64]
Ids = npt.NDArray[np.int64]
Mask = npt.NDArray[np.bool_]


class AgentRunner:
    """Agents ``ids``: ``x_i[k]`` now, and what each remembers of its in-links."""

    def __init__(
        self, scenario: Scenario, ids: list[int], strategy: StrategyName, seed: int
    ) -> None:
        for i in ids:
            if not 1 <= i <= scenario.n:
                raise ValueError(
                    f"agent id {i} is not in the scenario (agents are 1..{scenario.n})"
                )
        self.scenario, self.ids, self.strategy, self.seed = scenario, list(ids), strategy, seed
        self.row = {i: r for r, i in enumerate(self.ids)}
        self._agents = np.array(self.ids, dtype=np.int64)
        self.links = InLinks.of(scenario, np.array(self.ids))
        n_links, d = len(self.links.index), scenario.dimension
        # (receiver row, sender id) → in-link row, −1 where there is none
        self._link_row = np.full((len(ids), scenario.n + 1), -1, dtype=np.int64)
        self._link_row[self.links.receiver_row, self.links.sender] = np.arange(n_links)
        self._row_of = np.full(scenario.n + 1, -1, dtype=np.int64)  # agent id → row, −1: not ours
        self._row_of[self._agents] = np.arange(len(ids))
        rows = np.array(self.ids) - 1
        self.x = scenario.initial_positions(seed)[rows].copy()
        self.velocity = np.zeros((len(ids), d))
        self.unicycle = scenario.control.dynamics == "unicycle"
        # θ[k] [rad] and the sub-steps of epoch k − 1 with a clipped speed (unicycle only)
        self.heading = initial_headings(seed, scenario.n)[rows].copy() if self.unicycle else None
        self.saturated = np.zeros(len(ids), dtype=np.int64) if self.unicycle else None
        self.drive: Array | None = None  # (a, 2) the look-ahead velocity of epoch k − 1 [m/s]
        self.memory = LinkMemory.empty(n_links, d, state_width(strategy, d))
        self.v_known = np.zeros((len(ids), d))
        self.epoch = 0
        self.ref_row = self.row.get(scenario.reference_agent)
        if self.ref_row is not None:
            self._ref = reference_positions(
                scenario.reference,
                scenario.offsets[scenario.reference_agent - 1],
                scenario.control.period_s,
                scenario.epochs,
            )
            self.x[self.ref_row] = self._ref[0]
        self._arrived = np.zeros(n_links, dtype=bool)
        self._received = np.zeros((n_links, d))
        self._z = np.zeros((n_links, d))
        self.substituted: dict[int, list[tuple[int, list[float], bool]]] = {i: [] for i in ids}
        # Per in-link (receiver, sender) as Python ints: a pool walks them every epoch.
        self.pairs = list(
            zip(self.links.receiver.tolist(), self.links.sender.tolist(), strict=True)
        )
        self._positions: list[list[float]] | None = None
        self._noise = NoiseKeys(seed, self.links.receiver, self.links.sender)
        team = scenario.membership  # the scenario's events (formation.events)
        self._in_graph = None if team.everyone else team.in_graph[:, self.links.sender - 1]

    def resume(
        self,
        epoch: int,
        positions: dict[int, list[float] | None],
        headings: dict[int, float | None] | None = None,
    ) -> None:
        """Rejoin a running run at ``epoch``: each body where the run last saw it (None: where
        the scenario starts it), at rest, with no memory of its links (issue 20, restart);
        a unicycle facing its last recorded heading."""
        for i, p in positions.items():
            if p is not None:
                self.x[self.row[i]] = p
        for i, h in (headings or {}).items():
            if h is not None and self.heading is not None:
                self.heading[self.row[i]] = h
        self.velocity[:] = 0.0  # a crashed body stopped where it was
        d = self.scenario.dimension
        self.memory = LinkMemory.empty(len(self.links.index), d, state_width(self.strategy, d))
        self.v_known[:] = 0.0
        self.substituted = {i: [] for i in self.ids}
        self._positions = None
        self.epoch = epoch

    def place(
        self,
        positions: dict[int, list[float]],
        headings: dict[int, float] | None = None,
        saturated: dict[int, int] | None = None,
    ) -> None:
        """Set ``x_i[k]`` of some agents from their bodies' poses [m] (agent.body); a unicycle's
        ``θ_i[k]`` [rad] and the sub-steps of epoch ``k − 1`` whose twist was clipped."""
        for i, p in positions.items():
            self.x[self.row[i]] = p
        if self.heading is not None and self.saturated is not None:
            for i, h in (headings or {}).items():
                self.heading[self.row[i]] = h
            for i, count in (saturated or {}).items():
                self.saturated[self.row[i]] = count
        self._positions = None

    def poses(self, agents: list[int]) -> list[tuple[float, int]] | None:
        """Each unicycle's heading ``θ_i[k]`` [rad] and its saturated sub-steps of epoch
        ``k − 1`` (None: not unicycles)."""
        if self.heading is None or self.saturated is None:
            return None
        rows = self.rows(np.array(agents, dtype=np.int64))
        return list(zip(self.heading[rows].tolist(), self.saturated[rows].tolist(), strict=True))

    def position(self, agent: int) -> list[float]:
        if self._positions is None:
            self._positions = self.x.tolist()  # one conversion for the whole pool
        return self._positions[self.row[agent]]

    def rows(self, agents: Ids) -> Ids:
        """(m,) each agent's row (every one of ``agents`` is one of these)."""
        return self._row_of[agents]

    def link_rows(self, receivers: Ids, senders: Ids) -> Ids:
        """(m,) the in-link row of each ``senders[m] → receivers[m]``, −1 where none is ours."""
        n = self.scenario.n
        inside = (receivers >= 0) & (receivers <= n) & (senders >= 0) & (senders <= n)
        rows = np.full(receivers.shape, -1, dtype=np.int64)
        r = self._row_of[receivers[inside]]
        found = np.full(r.shape, -1, dtype=np.int64)
        ours = r >= 0
        found[ours] = self._link_row[r[ours], senders[inside][ours]]
        rows[inside] = found
        return rows

    def receive(self, receivers: Ids, sources: Ids, sent_epoch: Ids, positions: Array) -> None:
        """Epoch ``k``'s delivered packets (m,), each ``x_j`` (m, d) [m], into the agents' links:
        :attr:`arrived` and :attr:`z` are then each in-link's token and measurement.

        Packets sent before ``k`` (delayed) only refresh the held value; where several reach
        one link, the last one sent (and of those the last delivered) counts.
        """
        k, n_links, d = self.epoch, len(self.links.index), self.scenario.dimension
        if positions.shape != (receivers.shape[0], d):
            raise ValueError(
                f"positions have shape {positions.shape}; expected ({len(receivers)}, {d})"
            )
        rows = self.link_rows(receivers, sources)
        late = np.flatnonzero((sent_epoch < k) & (rows >= 0))
        if late.size:
            late = _last_per_row(rows, late[np.argsort(sent_epoch[late], kind="stable")])
            values = np.zeros((n_links, d))
            sent = np.full(n_links, -1, dtype=np.int64)
            mask = np.zeros(n_links, dtype=bool)
            values[rows[late]], sent[rows[late]], mask[rows[late]] = (
                positions[late],
                sent_epoch[late],
                True,
            )
            self.memory = self.memory.receive_late(values, sent, mask)
        now = _last_per_row(rows, np.flatnonzero((sent_epoch == k) & (rows >= 0)))
        self._arrived[:] = False
        self._received[:] = 0.0
        self._arrived[rows[now]] = True
        self._received[rows[now]] = positions[now]
        self._z = relative_measurement(
            self.x[self.links.receiver_row],
            self._received,
            self.scenario.noise_covariance,
            self.seed,
            self.links.receiver,
            self.links.sender,
            k,
            self._noise,
        )

    @property
    def arrived(self) -> Mask:
        """(L,) each in-link's packet of this epoch arrived in time (its token)."""
        return self._arrived

    @property
    def z(self) -> Array:
        """(L, d) each in-link's relative measurement ``z_ij`` [m] (meaningful where arrived)."""
        return self._z

    def step(self, v_ref: Array, has_v_ref: Mask, estimate: Array, has_estimate: Mask) -> None:
        """Close epoch ``k`` with what the leader's messages gave: ``v_ref`` (a, d) [m/s] where
        ``has_v_ref`` (a,) (an agent's message came), and the in-links' ``x̂_j`` (L, d) [m]
        where ``has_estimate`` (L,); ``x`` becomes ``x[k+1]``."""
        k, n_links = self.epoch, len(self.links.index)
        v_prev = self.v_known.copy()
        self.v_known[has_v_ref] = v_ref[has_v_ref]
        est, has = estimate, has_estimate
        v_before = v_prev[self.links.receiver_row]
        if self._in_graph is None or self._in_graph[k].all():
            result = agent_epoch(
                self.scenario,
                self.strategy,
                k,
                self.links,
                self.x,
                self.velocity,
                self._arrived,
                self._received,
                self._z,
                self.memory,
                est,
                has,
                v_before,
                self.v_known,
                headings=self.heading,
                agents=self._agents,
            )
            self.memory, sub = result.memory, result.substitution
        else:  # a neighbour out of the team: its edge leaves the consensus, its memory waits
            rows = np.flatnonzero(self._in_graph[k])
            result = agent_epoch(
                self.scenario,
                self.strategy,
                k,
                self.links.take(rows),
                self.x,
                self.velocity,
                self._arrived[rows],
                self._received[rows],
                self._z[rows],
                self.memory.take(rows),
                est[rows],
                has[rows],
                v_before[rows],
                self.v_known,
                headings=self.heading,
                agents=self._agents,
            )
            self.memory = self.memory.put(rows, result.memory)
            sub = result.substitution.spread(rows, n_links)
        self.velocity = result.velocities
        x_before, self.x, self.drive = self.x, result.positions, result.drive
        self._positions = None
        before = self.heading
        if result.headings is not None and result.saturated is not None:
            self.heading, self.saturated = result.headings, result.saturated
        if self.ref_row is not None:
            self.x[self.ref_row] = self._ref[k + 1]
            if before is not None and self.heading is not None and self.saturated is not None:
                step = self._ref[k + 1] - self._ref[k]
                self.heading[self.ref_row] = reference_heading(before[self.ref_row], step)
                self.saturated[self.ref_row] = 0  # it does not steer by its command
            if self.drive is not None:  # its robot's, toward the trajectory (testbed/sim/bodies.py)
                period_s = self.scenario.control.period_s
                self.drive[self.ref_row] = body_velocity(
                    x_before[self.ref_row], self._ref[k + 1], period_s
                )
        self.substituted = {i: [] for i in self.ids}
        for row in np.flatnonzero(sub.substituted).tolist():
            receiver, sender = self.pairs[row]
            self.substituted[receiver].append(
                (sender, sub.values[row].tolist(), bool(sub.fallback[row]))
            )
        self.epoch = k + 1


def _last_per_row(rows: Ids, order: Ids) -> Ids:
    """The entries of ``order`` (indices into ``rows``) that are the last of their row in it."""
    if order.size < 2 or np.bincount(rows[order]).max() < 2:  # no row twice: all of them
        return order
    _, last = np.unique(rows[order][::-1], return_index=True)
    return order[order.size - 1 - last]
