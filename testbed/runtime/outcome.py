"""What a run of real processes produced, as the launcher observed it over Zenoh: the states,
netem's decisions, the counts, the losses, and the summary written beside the recording."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from analysis import (
    RunData,
    air_losses,
    formation_error,
    loss_split,
    present,
    shape_error,
    spans,
    summarise,
)
from formation import realtime_accounting
from formation.body import BODY_LOST_EXIT
from formation.scenario import Scenario
from testbed.runtime.events import bodies
from testbed.runtime.faults import agent_ids
from testbed.runtime.observer import Verdict


@dataclass
class Supervision:
    """What the launcher saw of a run beside its states: the nodes' deadline counts, the
    processes lost, the estimates that fell back, netem's team events, the priorities it set
    and the CPU the hypervisor took."""

    deadline: dict[str, int] = field(default_factory=dict)  # formation.deadline_counts
    losses: list[dict[str, Any]] = field(default_factory=list)  # testbed.runtime.faults.Loss
    fallbacks: int = 0  # substituted values that fell back to hold (no estimate to use)
    fallback_epochs: dict[int, int] = field(default_factory=dict)  # epoch → those used at it
    team_events: list[tuple[float, str]] = field(default_factory=list)  # (monotonic t [s], detail)
    priorities: str | None = None  # realtime: what the launcher set, as a line
    cpu_steal: float | None = None  # the hypervisor's share of the CPU during the run


@dataclass
class RunOutcome:
    """What a distributed run produced, as the launcher observed it over Zenoh."""

    run_id: str
    run_dir: Path
    scenario: Scenario
    strategy: str
    seed: int
    positions: npt.NDArray[np.float64]  # (E + 1, n, d) true states x[k] [m], NaN where never seen
    estimated_epochs: list[int]  # epochs whose estimate the leader published
    decisions: list[Verdict]
    malformed: dict[str, int]
    sent: dict[str, int]  # messages published per key
    pids: list[int]
    wall_s: float
    substitutions: list[tuple[int, int, int, list[float]]]
    supervision: Supervision = field(default_factory=Supervision)
    delivered: dict[str, int] = field(default_factory=dict)  # packets netem delivered per link

    @property
    def bodies(self) -> npt.NDArray[np.float64]:
        """(E + 1, n, d) positions, a body without a state where it last was (events, losses)."""
        return bodies(self.positions, self.scenario.initial_positions(self.seed))

    @property
    def formation_error(self) -> npt.NDArray[np.float64]:
        return formation_error(self.bodies, self.scenario.edge_array, self.scenario.weights)

    @property
    def shape_error(self) -> npt.NDArray[np.float64]:
        return shape_error(self.bodies, self.scenario.edge_array, self.scenario.offsets)

    def drops_per_link(self) -> dict[str, tuple[int, int]]:
        """``"src->dst" → (sent, dropped)`` over every decision."""
        sent: Counter[str] = Counter()
        dropped: Counter[str] = Counter()
        for d in self.decisions:
            link = f"{d.source}->{d.target}"
            sent[link] += 1
            dropped[link] += d.verdict == "drop"
        return {k: (sent[k], dropped[k]) for k in sorted(sent)}

    def substitution_errors(self) -> npt.NDArray[np.float64]:
        """``x̃_j[k] − x_j[k]`` of every substituted variable, ordered by (epoch, agent, neighbour)."""
        d = self.scenario.dimension
        rows = [np.asarray(v) - self.positions[k, j - 1] for k, _, j, v in self.substitutions]
        return np.array(rows).reshape(-1, d)

    def deadline_accounting(self) -> dict[str, Any]:
        """Realtime: modelled losses, deadline misses by cause, in time (lockstep: no rate)."""
        seen = self.supervision
        return realtime_accounting(
            seen.deadline, self.drops_per_link(), seen.cpu_steal, self.untaken_for_lost_robots()
        )

    def untaken_for_lost_robots(self) -> int:
        """Packets netem delivered to an agent whose robot was lost, of the epochs it never
        took: from its loss's epoch − 1 (it publishes ``x[k+1]`` before it waits for the pose)."""
        untaken_from = {
            i: int(loss["epoch"]) - 1
            for loss in self.supervision.losses
            if loss.get("code") == BODY_LOST_EXIT and loss["name"] != "leader"
            for i in agent_ids(loss["name"])  # a pool's agents stop with its robot
        }
        return sum(
            d.verdict != "drop" and d.epoch >= untaken_from.get(d.target, d.epoch + 1)
            for d in self.decisions
        )

    def deadline_miss_rate(self) -> float | None:
        """Realtime: deadline misses of the testbed's own making, over the packets sent."""
        return self.deadline_accounting().get("deadline_miss_rate")

    def record(self) -> RunData:
        """What the launcher saw as a run's record: the states (in the team: a state seen)
        and the substitutions; the leader's outputs and the deliveries are the recording's."""
        sc = self.scenario
        n, d, m = sc.n, sc.dimension, len(sc.edges)
        none = np.zeros(0, dtype=np.int64)
        return RunData(
            label=self.strategy,
            scenario=sc,
            strategy=self.strategy,
            seed=self.seed,
            positions=self.positions,
            formation_error=self.formation_error,
            shape_error=self.shape_error,
            estimates=np.zeros((0, n, d)),
            estimate_cov=np.zeros((0, n, d, d)),
            observable=np.zeros((0, n), dtype=bool),
            delivered=np.zeros((0, len(sc.directed_links)), dtype=bool),
            healthy=np.zeros((0, m), dtype=bool),
            tree=np.zeros((0, m), dtype=bool),
            components=none,
            rigidity_rank=none,
            substitution_errors=self.substitution_errors(),
            nees_values=np.zeros(0),
            estimation_errors=np.zeros((0, d)),
            source=str(self.run_dir),
        )

    @cached_property
    def headline(self) -> dict[str, Any]:
        """:func:`analysis.summarise` of :meth:`record`, once (its safety counts are O(n²))."""
        return summarise(self.record())

    def summary(self) -> dict[str, Any]:
        drops = self.drops_per_link()
        headline = self.headline  # the team's final errors, as every summary's
        return {
            "run_id": self.run_id,
            "strategy": self.strategy,
            "seed": self.seed,
            "epochs": int(self.positions.shape[0] - 1),
            "final_formation_error_m": headline["final_formation_error_m"],
            "final_shape_error_m": headline["final_shape_error_m"],
            "packets_sent": sum(s for s, _ in drops.values()),
            "packets_dropped": sum(d for _, d in drops.values()),
            "dropped_links": {k: v for k, v in drops.items() if v[1]},
            **self.capacity_losses(),
            "malformed": self.malformed,
            "mode": self.scenario.runtime.mode,
            "deadline": self.supervision.deadline,
            **self.deadline_accounting(),
            "priorities": self.supervision.priorities,
            "cpu_steal": self.supervision.cpu_steal,
            "wall_s": self.wall_s,
            **self.faults_summary(),
        }

    def capacity_losses(self) -> dict[str, Any]:
        """With capacity queues: the drops split into channel, queue and deadline losses; with
        the shared air: its drops by cause."""
        out: dict[str, Any] = {}
        if self.scenario.network.capacity:
            out["loss_split"] = loss_split(self.decisions)
        if self.scenario.network.air is not None:
            out["air_losses"] = air_losses(self.decisions)
        return out

    def faults_summary(self) -> dict[str, Any]:
        """Who died, when and whether it came back, and who was in the team at each epoch
        (``team``: agent → its spans of epochs with a state, with losses and whenever some
        agent lacks a state at some epoch, as with the scenario's events)."""
        losses = self.supervision.losses
        seen = present(self.positions)
        out: dict[str, Any] = {}
        if losses or not seen.all():
            out["team"] = {str(i): s for i, s in spans(seen).items()}
        if not losses:
            return out
        drops = self.drops_per_link()
        links = self.scenario.directed_links
        for loss in losses:  # its drops: decisions on its links, and the epochs it missed
            name = loss["name"]
            ids = [0] if name == "leader" else agent_ids(name)  # a pool: each of its agents
            loss["dropped"] = sum(
                d for link, (_, d) in drops.items() if {str(i) for i in ids} & set(link.split("->"))
            )
            if name != "leader":  # the states its receivers went without while it was out
                loss["missed"] = sum(
                    int((~seen[loss["epoch"] :, i - 1]).sum()) * int((links[:, 0] == i).sum())
                    for i in ids
                )
        return {"losses": losses, **out, "fallbacks": self.supervision.fallbacks}
