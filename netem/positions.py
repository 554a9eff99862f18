"""The agents' true positions per epoch, as netem reads them, for the distance link models.

A distance model (``range``, ``logistic``, ``log_distance``) decides link ``i → j``
of epoch ``k`` by the distance between ``x_i[k]`` and ``x_j[k]`` (a control link's
leader end is the scenario's ``network.access_point``). netem reads ``x_i[k]`` from
agent ``i``'s state packet of epoch ``k``, decoded only when such a model is
configured. A packet whose decision needs a position netem has not read yet is held
(:meth:`Positions.admit`) and handed back once it has (:meth:`Positions.release`):
an agent's epoch-``k`` state never waits on anything of epoch ``k``, so nothing
waits forever. A state whose position cannot be read counts (``malformed``) and
puts its sender out of range for that epoch.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Collection, Iterator
from typing import Any

import numpy as np
import orjson

from formation.scenario import LEADER_ENDPOINT
from netem.layer import Floats, Ints
from netem.links import Link, Links, Route
from netem.matrix import link_length, link_lengths

Held = tuple[Route, int, int, Any]  # (route, epoch, seq, payload) of a packet put back
KEEP_EPOCHS = 256  # positions of older epochs are forgotten (lockstep never lags that far)


def _position(payload: Any) -> list[float] | None:
    """``position`` of a state payload (bytes or ZBytes); None when it is not a list of numbers."""
    raw = payload.to_bytes() if hasattr(payload, "to_bytes") else payload
    try:
        msg = orjson.loads(raw)
    except orjson.JSONDecodeError:
        return None
    pos = msg.get("position") if isinstance(msg, dict) else None
    if not isinstance(pos, list) or not pos or not all(isinstance(v, int | float) for v in pos):
        return None
    return [float(v) for v in pos]


class Positions:
    """Positions read per epoch, and the packets held until the positions they need are read."""

    def __init__(self, links: Links) -> None:
        self.links = links
        self.access_point = links.access_point
        self.at: dict[int, dict[int, list[float] | None]] = defaultdict(dict)  # epoch → agent →
        self.held: dict[tuple[int, int], list[Held]] = defaultdict(list)  # (epoch, agent) awaited
        self.malformed = 0
        self._ready: list[tuple[int, int]] = []  # (epoch, agent) whose position just came
        self._ends: dict[tuple[Link, ...], tuple[Ints, Ints]] = {}  # links → rows of their ends
        self.refresh()

    def refresh(self) -> None:
        """Which links have a distance model (again, after a change of models)."""
        self.ranged: set[Link] = {link for link, m in self.links.models.items() if m.ranged}
        self.needed = bool(self.ranged)

    def _needs(self, route: Route, epoch: int, dead: Collection[int]) -> int | None:
        """An agent whose epoch position the packet's decisions need and netem lacks; None if none."""
        kind, source, target = route
        known = self.at.get(epoch, {})
        if kind == "state":
            for dst in self.links.out_links[source]:
                if (
                    ("formation", source, dst) in self.ranged
                    and dst not in known
                    and dst not in dead
                ):
                    return dst
            return None
        agent, link = (
            (source, ("report", source, LEADER_ENDPOINT))
            if kind == "report"
            else (target, ("estimate", LEADER_ENDPOINT, target))
        )
        if link in self.ranged and agent not in known and agent not in dead:
            return agent
        return None

    def admit(
        self, route: Route, epoch: int, seq: int, payload: Any, dead: Collection[int]
    ) -> bool:
        """Read a state's position; True when the packet can be decided now, else it is held."""
        kind, source, _ = route
        if kind == "state" and source not in self.at.get(epoch, {}):
            pos = _position(payload)
            if pos is None:
                self.malformed += 1
            self.at[epoch][source] = pos
            self._ready.append((epoch, source))
            self.at.pop(epoch - KEEP_EPOCHS, None)
        waiting = self._needs(route, epoch, dead)
        if waiting is None:
            return True
        self.held[(epoch, waiting)].append((route, epoch, seq, payload))
        return False

    def release(self, dead: Collection[int]) -> Iterator[Held]:
        """The held packets that can be decided now (positions read, or their agent gone)."""
        while self._ready or (dead and any(a in dead for _, a in self.held)):
            keys = self._ready + [k for k in self.held if k[1] in dead]
            self._ready = []
            for key in keys:
                for route, epoch, seq, payload in self.held.pop(key, []):
                    if self.admit(route, epoch, seq, payload, dead):
                        yield route, epoch, seq, payload

    def length(self, link: Link, epoch: int) -> float | None:
        """The length [m] of ``link`` at ``epoch`` if it has a distance model, else None.

        An end whose position is unreadable makes the link infinitely long (out of range).
        """
        if link not in self.ranged:
            return None
        return self._measure(link, self.at.get(epoch, {}))

    def lengths(self, links: tuple[Link, ...], epoch: int) -> Floats:
        """The lengths ``(len(links),)`` [m] of formation ``links`` at ``epoch``, vectorised: each
        what :meth:`length` gives (:func:`link_lengths` and :func:`link_length` agree bit for bit)."""
        known = self.at.get(epoch, {})
        rows = [known.get(i) for i in self.links.agents]
        ends = self._ends.get(links)
        if ends is None:
            row = {agent: r for r, agent in enumerate(self.links.agents)}
            ends = self._ends[links] = (
                np.array([row[src] for _, src, _ in links], dtype=np.int64),
                np.array([row[dst] for _, _, dst in links], dtype=np.int64),
            )
        if None not in rows:
            x = np.array(rows, dtype=object)
            if x.ndim == 2:  # every position has as many coordinates
                x = x.astype(np.float64)
                return link_lengths(x[ends[0]], x[ends[1]])
        return np.array([self._measure(link, known) for link in links], dtype=np.float64)

    def _measure(self, link: Link, known: dict[int, list[float] | None]) -> float:
        _, src, dst = link
        a = self.access_point if src == LEADER_ENDPOINT else known.get(src)
        b = self.access_point if dst == LEADER_ENDPOINT else known.get(dst)
        if a is None or b is None or len(a) != len(b):
            return math.inf
        return link_length(a, b)


__all__ = ["KEEP_EPOCHS", "Held", "Positions"]
