"""Who takes part in netem's lockstep at which epoch: the team's plan, senders down and back.

The plan comes from the scenario alone, so every run drops the same: the agents out of the
team at each epoch (left, crashed, not yet joined), each agent's scheduled (re)starts, and
who is away at the start (docs/model.md). Deaths and returns come as netem sees them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from formation.events import Membership


@dataclass(frozen=True)
class TeamPlan:
    """out: epoch → agents out then; starts: agent → epochs it (re)starts (> 0); away at 0."""

    out: dict[int, frozenset[int]] = field(default_factory=dict)
    starts: dict[int, list[int]] = field(default_factory=dict)
    away: frozenset[int] = frozenset()

    @classmethod
    def of(cls, team: Membership | None, epochs: int, agents: Sequence[int]) -> TeamPlan:
        """The plan of ``team`` over epochs ``0..epochs``; empty without events."""
        if team is None:
            return cls()
        out = {
            k: frozenset(int(i) + 1 for i in (~team.present[k]).nonzero()[0])
            for k in range(epochs + 1)
            if not team.present[k].all()
        }
        starts = {i: [k for k, _ in team.incarnations(i) if k > 0] for i in agents}
        away = frozenset(i for i in agents if not team.present[0, i - 1])
        return cls(out, starts, away)


class Attendance:
    """The team's plan and the senders down (agents, or the leader as 0) and back."""

    def __init__(self, team: Membership | None, epochs: int, agents: Sequence[int]) -> None:
        self.team, self.epochs = team, epochs
        plan = TeamPlan.of(team, epochs, agents)
        self.out, self.starts, self.away = plan.out, plan.starts, set(plan.away)
        self.dead: set[int] = set()
        self.revive: dict[int, int] = {}  # a dead sender back takes part from this epoch on
        self.rejoined: dict[int, int] = {}  # agent → the epoch of its scheduled start, once given
        # (action, agent, epoch) of each event as it is applied, for the node to announce.
        self.applied: list[tuple[str, int, int]] = []
        self.last_state: dict[int, tuple[int, Any]] = {}  # agent → (epoch, payload) last handled

    def planned_start(self, agent: int) -> int | None:
        """The epoch of ``agent``'s next scheduled join or restart, None if it has none."""
        if agent in self.rejoined:
            return self.rejoined[agent]
        starts = self.starts.get(agent)
        if not starts:
            return None
        last = self.last_state[agent][0] if agent in self.last_state else -1
        return next((k for k in starts if k > last), None)

    def start(self, agent: int, epoch: int) -> None:
        """``agent`` takes part from its scheduled (re)start at ``epoch``."""
        self.rejoined[agent] = epoch
        self.away.discard(agent)
        again = self.team is not None and bool(self.team.present[:epoch, agent - 1].any())
        self.applied.append(("restart" if again else "join", agent, epoch))

    def leave(self, agent: int, epoch: int) -> None:
        """``agent`` is out by a leave or crash event from ``epoch``: nobody waits for its packets
        until its next scheduled start."""
        if agent not in self.away:
            crash = self.team is not None and bool(self.team.crashed[epoch, agent - 1])
            self.applied.append(("crash" if crash else "leave", agent, epoch))
        self.away.add(agent)
        self.rejoined.pop(agent, None)

    def back(self, agent: int, epoch: int) -> int:
        """The first epoch from ``epoch`` at which ``agent`` takes part again (or the end)."""
        return next((k for k in self.starts.get(agent, []) if k > epoch), self.epochs)

    def is_dead(self, sender: int, epoch: int) -> bool:
        """Whether ``sender``'s packets of ``epoch`` count as lost without waiting for them."""
        if self.out and sender in self.out.get(epoch, ()):
            return True
        if sender not in self.dead:
            return False
        back = self.revive.get(sender)
        return back is None or epoch < back

    def is_down(self, sender: int) -> bool:
        """Down now, and not yet back (the liveliness watch looks for a second death otherwise)."""
        return sender in self.dead and sender not in self.revive

    def state_of(self, agent: int) -> tuple[int, Any] | None:
        """``(epoch, payload)`` of the last state netem handled from ``agent``, if any."""
        return self.last_state.get(agent)

    def dead_at(self, epoch: int) -> set[int]:
        """The senders whose packets of ``epoch`` nobody waits for."""
        out = self.out.get(epoch) if self.out else None
        dead = self.dead if not self.revive else {s for s in self.dead if self.is_dead(s, epoch)}
        return dead | out if out else dead

    def gone(self) -> set[int]:
        """The senders down and not back, and the agents out at the end."""
        down = {s for s in self.dead if s not in self.revive}
        return down | self.out.get(self.epochs, frozenset())
