"""One agent's epoch-by-epoch state, with no network: the node feeds it what arrived.

The same :func:`agent.epoch.agent_epoch` the simulator runs, applied to this
agent and its in-links.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from agent.epoch import InLinks, agent_epoch
from agent.measurement import relative_measurement
from agent.strategies import LinkMemory, StrategyName
from formation.reference import reference_positions
from formation.scenario import Scenario

Array = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Packet:
    """A coordination packet as delivered: its source, the epoch it was sent, ``x_j`` [m]."""

    source: int
    sent_epoch: int
    position: tuple[float, ...]


class AgentRunner:
    """Agent ``agent_id``: ``x_i[k]`` now, and what it remembers of its in-links."""

    def __init__(
        self, scenario: Scenario, agent_id: int, strategy: StrategyName, seed: int
    ) -> None:
        if not 1 <= agent_id <= scenario.n:
            raise ValueError(
                f"agent id {agent_id} is not in the scenario (agents are 1..{scenario.n})"
            )
        self.scenario, self.id, self.strategy, self.seed = scenario, agent_id, strategy, seed
        self.is_reference = agent_id == scenario.leader
        self.links = InLinks.of(scenario, np.array([agent_id]))
        d = scenario.dimension
        self.x = scenario.initial_positions(seed)[agent_id - 1 : agent_id].copy()
        self.velocity = np.zeros((1, d))
        self.memory = LinkMemory.empty(len(self.links.index), d)
        self.v_known = np.zeros((1, d))
        self.epoch = 0
        if self.is_reference:
            self._ref = reference_positions(
                scenario.reference,
                scenario.offsets[agent_id - 1],
                scenario.control.period_s,
                scenario.epochs,
            )
            self.x = self._ref[0:1].copy()
        self._arrived = np.zeros(len(self.links.index), dtype=bool)
        self._received = np.zeros((len(self.links.index), d))
        self._z = np.zeros((len(self.links.index), d))
        self.substituted: list[tuple[int, list[float], bool]] = []  # used at the last step

    @property
    def neighbours(self) -> list[int]:
        return [int(s) for s in self.links.sender]

    @property
    def position(self) -> list[float]:
        return [float(v) for v in self.x[0]]

    def receive(self, packets: list[Packet]) -> list[tuple[int, int, list[float] | None]]:
        """Epoch ``k``'s delivered packets → the report: ``(neighbour, token, z_ij)`` per in-link.

        Packets sent before ``k`` (delayed) only refresh the held value.
        """
        k, n_links = self.epoch, len(self.links.index)
        row = {int(s): r for r, s in enumerate(self.links.sender)}
        late = [p for p in packets if p.sent_epoch < k and p.source in row]
        if late:
            values = np.zeros((n_links, self.scenario.dimension))
            sent = np.full(n_links, -1, dtype=np.int64)
            mask = np.zeros(n_links, dtype=bool)
            for p in sorted(late, key=lambda p: p.sent_epoch):
                values[row[p.source]], sent[row[p.source]], mask[row[p.source]] = (
                    p.position,
                    p.sent_epoch,
                    True,
                )
            self.memory = self.memory.receive_late(values, sent, mask)
        self._arrived[:] = False
        self._received[:] = 0.0
        for p in packets:
            if p.sent_epoch == k and p.source in row:
                self._arrived[row[p.source]] = True
                self._received[row[p.source]] = p.position
        self._z = relative_measurement(
            np.repeat(self.x, n_links, axis=0), self._received, self.scenario.noise_covariance,
            self.seed, self.links.receiver, self.links.sender, k,
        )  # fmt: skip
        return [
            (int(s), int(a), [float(v) for v in self._z[r]] if a else None)
            for r, (s, a) in enumerate(zip(self.links.sender, self._arrived, strict=True))
        ]

    def step(
        self, estimate: list[list[float] | None] | None, v_ref: list[float] | None
    ) -> list[float]:
        """Close epoch ``k`` with the leader's estimate (None if it was lost); returns ``x_i[k+1]``."""
        k, n_links, d = self.epoch, len(self.links.index), self.scenario.dimension
        v_prev = self.v_known.copy()
        if v_ref is not None:
            self.v_known = np.array([v_ref], dtype=float)
        est = np.zeros((n_links, d))
        has = np.zeros(n_links, dtype=bool)
        if estimate is not None:
            for r, s in enumerate(self.links.sender):
                value = estimate[int(s) - 1]
                if value is not None:
                    est[r], has[r] = value, True
        result = agent_epoch(
            self.scenario, self.strategy, k, self.links, self.x, self.velocity, self._arrived,
            self._received, self._z, self.memory, est, has, np.repeat(v_prev, n_links, axis=0), self.v_known,
        )  # fmt: skip
        self.memory, self.velocity = result.memory, result.velocities
        self.x = self._ref[k + 1 : k + 2].copy() if self.is_reference else result.positions
        sub = result.substitution
        self.substituted = [
            (int(s), [float(v) for v in sub.values[r]], bool(sub.fallback[r]))
            for r, s in enumerate(self.links.sender)
            if sub.substituted[r]
        ]
        self.epoch = k + 1
        return self.position
