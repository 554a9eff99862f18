"""The team a scenario's events plan, as netem's lockstep drops by it (docs/model.md, issue 20).

From the scenario alone, so every run drops the same: the agents out of the team at each
epoch (left, crashed, not yet joined), each agent's scheduled (re)starts, and who is away
at the start.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

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
