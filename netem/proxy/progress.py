"""How far the senders have got, as netem has seen them: what ``netem/final`` answers from.

A sender leaves only once netem has its last messages: an agent's final state (its
packet of epoch ``epochs``) and the leader's estimates of every epoch.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Collection


class Progress:
    """Newest epoch seen, agents whose final state came, epochs whose estimates all came.

    ``on_change`` is called after a final state or a finished epoch of estimates (the
    shell wakes the queries waiting on them).
    """

    def __init__(self, agents: list[int], epochs: int, on_change: Callable[[], None]) -> None:
        self.agents, self.epochs = agents, epochs
        self.on_change = on_change
        self.epoch_seen = 0
        self.final_states: set[int] = set()
        self.estimates_done = 0  # epochs 0 .. estimates_done - 1 had all their estimates
        self._estimates_seen: Counter[int] = Counter()  # epoch → agents' estimates handled

    def final_state(self, agent: int) -> None:
        self.final_states.add(agent)
        self.on_change()

    def estimate_handled(self, epoch: int, count: int = 1) -> None:
        """The leader sends one estimate per agent: the epoch is done once all were handled
        (``count`` of them handled now)."""
        self._estimates_seen[epoch] += count
        if self._estimates_seen[epoch] >= len(self.agents):
            del self._estimates_seen[epoch]
            self.estimates_done = max(self.estimates_done, epoch + 1)
            self.on_change()

    def estimate_skipped(self, epoch: int) -> None:
        """The leader is down at ``epoch``: its estimates will not come (agents fall back)."""
        self.estimates_done = max(self.estimates_done, epoch + 1)
        self.on_change()

    def finished(self, dead: Collection[int]) -> bool:
        """Every estimate handled, and every live agent's final state seen."""
        live = [i for i in self.agents if i not in dead]
        return self.estimates_done >= self.epochs and all(i in self.final_states for i in live)
