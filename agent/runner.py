"""The epoch-by-epoch state of a set of agents (one, or a pool), with no network.

The node feeds it what arrived; it runs the same :func:`agent.epoch.agent_epoch`
the simulator runs, on these agents and their in-links at once.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

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
Report = list[tuple[int, int, list[float] | None]]  # (neighbour, token, z_ij) per in-link


class Packet(NamedTuple):
    """A coordination packet as delivered to ``receiver``: its source, sent epoch and ``x_j`` [m].

    A tuple: a pool builds hundreds an epoch."""

    receiver: int
    source: int
    sent_epoch: int
    position: tuple[float, ...]


@dataclass(frozen=True)
class Estimate:
    """What the leader's epoch-``k`` message gave one agent: ``x̂_j`` per in-neighbour ``j``
    (None: unobservable), and ``v_ref``."""

    positions: dict[int, list[float] | None]
    v_ref: list[float]


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
        self.link_of = {
            (int(b), int(a)): r
            for r, (a, b) in enumerate(zip(self.links.sender, self.links.receiver, strict=True))
        }  # (receiver, sender) → in-link row
        n_links, d = len(self.links.index), scenario.dimension
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
        self._pairs = list(
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

    def pose(self, agent: int) -> tuple[float, int] | None:
        """A unicycle's heading ``θ_i[k]`` [rad] and its saturated sub-steps of epoch ``k − 1``."""
        if self.heading is None or self.saturated is None:
            return None
        r = self.row[agent]
        return float(self.heading[r]), int(self.saturated[r])

    def position(self, agent: int) -> list[float]:
        if self._positions is None:
            self._positions = self.x.tolist()  # one conversion for the whole pool
        return self._positions[self.row[agent]]

    def receive(self, packets: list[Packet]) -> dict[int, Report]:
        """Epoch ``k``'s delivered packets → each agent's report.

        Packets sent before ``k`` (delayed) only refresh the held value.
        """
        k, n_links = self.epoch, len(self.links.index)
        late = [p for p in packets if p.sent_epoch < k]
        if late:
            late.sort(key=lambda p: p.sent_epoch)
            values = np.zeros((n_links, self.scenario.dimension))
            sent = np.full(n_links, -1, dtype=np.int64)
            mask = np.zeros(n_links, dtype=bool)
            for p in late:
                r = self.link_of.get((p.receiver, p.source))
                if r is not None:
                    values[r], sent[r], mask[r] = p.position, p.sent_epoch, True
            self.memory = self.memory.receive_late(values, sent, mask)
        self._arrived[:] = False
        self._received[:] = 0.0
        for p in packets:
            r = self.link_of.get((p.receiver, p.source))
            if p.sent_epoch == k and r is not None:
                self._arrived[r] = True
                self._received[r] = p.position
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
        reports: dict[int, Report] = {i: [] for i in self.ids}
        z = self._z.tolist()
        for (i, j), a, z_ij in zip(self._pairs, self._arrived.tolist(), z, strict=True):
            reports[i].append((j, int(a), z_ij if a else None))
        return reports

    def step(self, estimates: dict[int, Estimate | None]) -> None:
        """Close epoch ``k`` with what each agent got from the leader (None if lost); ``x`` becomes ``x[k+1]``."""
        k, n_links, d = self.epoch, len(self.links.index), self.scenario.dimension
        v_prev = self.v_known.copy()
        for i, e in estimates.items():
            if e is not None:
                self.v_known[self.row[i]] = e.v_ref
        est = np.zeros((n_links, d))
        has = np.zeros(n_links, dtype=bool)
        for r, (i, j) in enumerate(self._pairs):
            e = estimates.get(i)
            value = None if e is None else e.positions.get(j)
            if value is not None:
                est[r], has[r] = value, True
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
            receiver, sender = self._pairs[row]
            self.substituted[receiver].append(
                (sender, sub.values[row].tolist(), bool(sub.fallback[row]))
            )
        self.epoch = k + 1
