"""Who the recorder waits for at each epoch: the scenario's plan, less what netem says is down.

The plan is the scenario's events (:attr:`formation.events.Membership.published`: an agent
publishes ``x[k]`` while it takes part, and at its leave's or crash's epoch). Unplanned
losses come from netem's team statuses (``status/netem/0``, a ``running`` status whose
detail is JSON with ``down``, the senders down now, and ``back``, sender → the epoch it
takes part again from; 0 is the leader). A sender down is not waited for at any epoch
still open, until the epoch it is back from. Pure: no clock, no I/O.
"""

from __future__ import annotations

import json
import math
from collections.abc import Collection
from typing import Any

import numpy as np
import numpy.typing as npt

from formation.keys import LEADER_ENDPOINT
from formation.scenario import Scenario

Mask = npt.NDArray[np.bool_]


def team_detail(detail: str) -> dict[str, Any] | None:
    """netem's team status detail as a dict, or None when ``detail`` is not one."""
    try:
        body = json.loads(detail)
    except ValueError:
        return None
    if not isinstance(body, dict) or not isinstance(body.get("down"), list):
        return None
    return body


class Roster:
    """The agents expected at each epoch and whether the leader's estimate of it may come."""

    def __init__(self, scenario: Scenario) -> None:
        team = scenario.membership
        self.n, self.last = scenario.n, scenario.epochs
        self._published, self._present = team.published, team.present
        self._links = scenario.directed_links
        self._out_until: dict[int, float] = {}  # sender → first epoch it is expected again
        self._planned: dict[int, frozenset[int]] = {}  # epoch → planned(epoch), built once

    def on_team(self, detail: dict[str, Any]) -> None:
        """netem's team status: who is down now, and from which epoch each is back."""
        down = {int(i) for i in detail.get("down", []) if isinstance(i, int)}
        for i in down:
            self._out_until[i] = math.inf
        back = detail.get("back", {})
        for key, epoch in back.items() if isinstance(back, dict) else ():
            i = int(key) if str(key).isdigit() else -1
            if i not in down and i in self._out_until and isinstance(epoch, int):
                self._out_until[i] = epoch

    def _out(self, sender: int, epoch: int) -> bool:
        return epoch < self._out_until.get(sender, -math.inf)

    def planned(self, epoch: int) -> frozenset[int]:
        """Agents the scenario has publish their state of ``epoch``."""
        k = min(epoch, self.last)
        if k not in self._planned:
            self._planned[k] = frozenset(int(i) + 1 for i in np.flatnonzero(self._published[k]))
        return self._planned[k]

    def expected(self, epoch: int) -> set[int]:
        """Agents whose state of ``epoch`` is to come: planned and not down."""
        return set(self.planned(epoch) - self._down(epoch))

    def complete(self, epoch: int, got: Collection[int]) -> bool:
        """Whether ``got`` has every expected agent; asked at each state, so a short ``got``
        is answered by its length, not by walking the team."""
        planned, down = self.planned(epoch), self._down(epoch) & self.planned(epoch)
        if len(got) < len(planned) - len(down):
            return False
        return planned - down <= set(got)

    def _down(self, epoch: int) -> set[int]:
        return {i for i in self._out_until if self._out(i, epoch)}

    def estimated(self, epoch: int) -> bool:
        """Whether the leader's estimate of ``epoch`` is to come (none of the final states)."""
        return epoch < self.last and not self._out(LEADER_ENDPOINT, epoch)

    def decisions(self, epoch: int, team: Mask) -> int:
        """netem's formation decisions of ``epoch``: one per directed link between agents
        that take part by the plan and whose state came (``team`` (n,))."""
        if epoch >= self.last:
            return 0
        on = self._present[epoch] & team
        return int((on[self._links[:, 0] - 1] & on[self._links[:, 1] - 1]).sum())


__all__ = ["Roster", "team_detail"]
