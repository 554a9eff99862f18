"""Scenario events (issue 20): agents that leave, join, crash and restart at given epochs.

An event takes effect at the start of its epoch ``c`` (docs/model.md §3 for the epoch):

* ``leave``: the agent's last state is ``x[c]`` (its goodbye); from ``c`` its edges leave the
  formation graph, and its body stays where it was.
* ``join``: the agent is absent until ``c`` (its edges out of the graph, its body at its
  initial position); from ``c`` it takes part.
* ``crash``: the agent's last state is ``x[c]``; its body stays there, at rest. Its edges stay
  in the graph: its packets are lost (the neighbours' strategies fill them) and the leader
  cannot observe it.
* ``restart``: a new process for a crashed agent takes part from ``c`` at its body's state
  (at rest, no memory of its links, no known ``v_ref``).

Every process (netem, the agents, the launcher, the simulator) derives the same
:class:`Membership` from the scenario alone, so a run with events is as reproducible as one
without.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt
from pydantic import BaseModel, ConfigDict, Field

from formation.graph import component_labels

Action = Literal["leave", "join", "crash", "restart"]
Mask = npt.NDArray[np.bool_]
Problem = tuple[str, object, str]

# Which action may follow which state of an agent, and the state it leads to.
_AFTER: dict[str, dict[str, str]] = {
    "present": {"leave": "left", "crash": "crashed"},
    "left": {"join": "present"},
    "absent": {"join": "present"},
    "crashed": {"restart": "present"},
}
_WHY = {
    "restart": "a restart needs a crash of that agent before it",
    "join": "a join needs the agent absent (not yet joined, or left) before it",
    "leave": "a leave needs the agent present before it",
    "crash": "a crash needs the agent present before it",
}


class Event(BaseModel):
    """One ``[[events]]`` entry: ``agent`` does ``action`` at the start of ``epoch``."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    epoch: int = Field(ge=1)
    agent: int
    action: Action


@dataclass(frozen=True)
class Membership:
    """Who takes part at each epoch; row ``k`` is epoch ``k`` (0..E), column ``i − 1`` agent ``i``.

    present : (E + 1, n) the agent's process takes part: publishes ``x[k]`` and steps
    in_graph : (E + 1, n) its edges are in the formation graph (present, or crashed)
    """

    present: Mask
    in_graph: Mask

    @property
    def everyone(self) -> bool:
        """True when nobody is ever out (a scenario without events)."""
        return bool(self.present.all())

    @property
    def crashed(self) -> Mask:
        """(E + 1, n) the body is there but its process is not."""
        return self.in_graph & ~self.present

    @property
    def starts(self) -> Mask:
        """(E + 1, n) a (new) process takes part from this epoch: a join or a restart."""
        out = np.zeros_like(self.present)
        out[1:] = self.present[1:] & ~self.present[:-1]
        return out

    @property
    def published(self) -> Mask:
        """(E + 1, n) the agent publishes ``x[k]``: present, or at its leave's or crash's epoch
        (its last state); what a recording holds and :meth:`incarnations` spans."""
        out = self.present.copy()
        out[1:] |= self.present[:-1]
        return out

    def taking_part(self, epoch: int) -> list[int]:
        """Ids of the agents present at ``epoch``."""
        return [int(i) + 1 for i in np.flatnonzero(self.present[min(epoch, len(self.present) - 1)])]

    def incarnations(self, agent: int) -> list[tuple[int, int]]:
        """``[(first, last)]`` epochs of each of ``agent``'s processes: it publishes ``x[first]``
        to ``x[last]`` (``last`` is a leave's or crash's epoch, or E)."""
        col = self.present[:, agent - 1]
        e = len(col) - 1
        on = np.concatenate(([False], col, [False])).astype(np.int8)
        edges = np.flatnonzero(np.diff(on))
        return [(int(a), min(int(b), e)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def membership(n: int, epochs: int, events: Sequence[Event]) -> Membership:
    """The membership ``events`` give a team of ``n`` over ``epochs`` epochs (later ones ignored)."""
    present = np.ones((epochs + 1, n), dtype=bool)
    in_graph = np.ones((epochs + 1, n), dtype=bool)
    for i in _absent_at_start(events):
        if 1 <= i <= n:
            present[:, i - 1] = in_graph[:, i - 1] = False
    for e in sorted(events, key=lambda e: e.epoch):
        if e.epoch > epochs or not 1 <= e.agent <= n:
            continue
        col, k = e.agent - 1, e.epoch
        if e.action in ("join", "restart"):
            present[k:, col] = in_graph[k:, col] = True
        else:
            present[k:, col] = False
            in_graph[k:, col] = e.action == "crash"
    return Membership(present, in_graph)


def _absent_at_start(events: Sequence[Event]) -> set[int]:
    """Agents whose first event is a join: absent until then."""
    first: dict[int, Event] = {}
    for e in sorted(events, key=lambda e: e.epoch):
        first.setdefault(e.agent, e)
    return {i for i, e in first.items() if e.action == "join"}


def event_problems(
    n: int,
    reference_agent: int,
    epochs: int,
    edges: npt.NDArray[np.int64],
    events: Sequence[Event],
    allow_split: bool,
) -> list[Problem]:
    """What is wrong with a schedule, as ``(field, value, problem)``; empty when nothing is."""
    for k, e in enumerate(events):
        if not 1 <= e.agent <= n:
            return [(f"events[{k}].agent", e.agent, f"agent does not exist (agents are 1..{n})")]
        if e.agent == reference_agent:
            return [
                (
                    f"events[{k}].agent",
                    e.agent,
                    "the reference agent follows the trajectory and takes part in every epoch",
                )
            ]
        if e.epoch >= epochs:
            return [
                (
                    f"events[{k}].epoch",
                    e.epoch,
                    f"past the end (epochs = {epochs}; an event takes effect at 1..{epochs - 1})",
                )
            ]
    order = sorted(range(len(events)), key=lambda k: events[k].epoch)
    absent = _absent_at_start(events)
    state = {i: "absent" if i in absent else "present" for i in range(1, n + 1)}
    seen: dict[tuple[int, int], int] = {}
    for k in order:
        e = events[k]
        if (e.agent, e.epoch) in seen:
            return [
                (
                    f"events[{k}].epoch",
                    e.epoch,
                    f"agent {e.agent} has another event at this "
                    f"epoch (events[{seen[(e.agent, e.epoch)]}])",
                )
            ]
        seen[(e.agent, e.epoch)] = k
        nxt = _AFTER[state[e.agent]].get(e.action)
        if nxt is None:
            return [
                (
                    f"events[{k}].action",
                    e.action,
                    f"agent {e.agent} is {state[e.agent]} at epoch {e.epoch}: {_WHY[e.action]}",
                )
            ]
        state[e.agent] = nxt
    if allow_split or not events:
        return []
    team = membership(n, epochs, events)
    checks: list[tuple[str, object, int]] = [("events", f"{len(events)} events", 0)]
    checks += [(f"events[{k}].action", events[k].action, events[k].epoch) for k in order]
    for field, value, epoch in checks:
        parts = split_of(team.present[epoch], edges)
        if len(parts) > 1:
            shown = " and ".join(str(p) for p in parts)
            return [
                (
                    field,
                    value,
                    f"from epoch {epoch} the team taking part is split into "
                    f"{shown}; set allow_split = true to allow it",
                )
            ]
    return []


def split_of(present: Mask, edges: npt.NDArray[np.int64]) -> list[list[int]]:
    """The connected parts of the team ``present`` (n,) over the edges between its agents."""
    ids = np.flatnonzero(present) + 1
    if ids.size <= 1:
        return [ids.tolist()]
    row = np.full(present.size + 1, -1, dtype=np.int64)
    row[ids] = np.arange(ids.size)
    keep = present[edges[:, 0] - 1] & present[edges[:, 1] - 1] if len(edges) else np.zeros(0, bool)
    labels = component_labels(int(ids.size), row[edges[keep]] + 1)
    return [ids[labels == c].tolist() for c in np.unique(labels).tolist()]


__all__ = ["Action", "Event", "Membership", "event_problems", "membership", "split_of"]
