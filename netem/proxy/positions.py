"""The agents' true positions per epoch, as netem reads them, for the distance link models.

A distance model (``range``, ``logistic``, ``log_distance``) decides link ``i → j``
of epoch ``k`` by the distance between ``x_i[k]`` and ``x_j[k]`` (a control link's
leader end is the scenario's ``network.access_point``). netem reads ``x_i[k]`` from
agent ``i``'s state packet of epoch ``k``, decoded only when such a model is
configured. A packet whose decision needs a position netem has not read yet is held
(:meth:`Positions.admit`) and handed back once it has (:meth:`Positions.release`):
an agent's epoch-``k`` state never waits on anything of epoch ``k``, so nothing
waits forever. It waits on each agent missing, counted once; one not waited for at the
epoch (down, out by the scenario's events) or gone meanwhile counts as read. A state
whose position cannot be read counts (``malformed``) and puts its sender out of range
for that epoch.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Iterator
from typing import Any

import numpy as np
import numpy.typing as npt
import orjson

from formation.keys import LEADER_ENDPOINT
from netem.links.layer import Ints
from netem.links.matrix import link_length, link_lengths
from netem.proxy.routes import Link, Links, Route

Held = tuple[Route, int, int, Any]  # (route, epoch, seq, payload) of a packet put back
KEEP_EPOCHS = 256  # positions of older epochs are forgotten (lockstep never lags that far)
VECTOR_LINKS = (
    48  # from about this many links numpy measures an epoch faster (14: 3x slower, 74: 1.4x faster)
)
_NUMBER = (float, int, bool)  # what orjson gives for a JSON number (and true/false, as before)


def _position(raw: bytes) -> list[float] | None:
    """``position`` of a state payload; None when it is not a list of numbers."""
    try:
        msg = orjson.loads(raw)
    except orjson.JSONDecodeError:
        return None
    pos = msg.get("position") if type(msg) is dict else None
    if type(pos) is not list or not pos:
        return None
    floats = True
    for v in pos:
        t = type(v)
        if t is not float:
            if t not in _NUMBER:
                return None
            floats = False
    return pos if floats else [float(v) for v in pos]


class _Wait:
    """A held packet and how many of the positions it needs are still to come."""

    __slots__ = ("held", "missing")

    def __init__(self, held: Held, missing: int) -> None:
        self.held, self.missing = held, missing


class Positions:
    """Positions read per epoch, and the packets held until the positions they need are read.

    A held packet waits on each agent whose position it lacks, counted once: it is handed
    back when the last of them is read (or gone), the held in the order they were held.
    """

    def __init__(self, links: Links) -> None:
        self.links = links
        self.access_point = links.access_point
        self.at: dict[int, dict[int, list[float] | None]] = {}  # epoch → agent → position
        self.malformed = 0
        self._waits: dict[tuple[int, int], list[_Wait]] = {}  # (epoch, agent) awaited → waits
        self._ready: list[tuple[int, int]] = []  # (epoch, agent) read or gone, someone waiting
        self._ends: dict[tuple[Link, ...], tuple[Ints, Ints]] = {}  # links → rows of their ends
        self._pairs: dict[tuple[Link, ...], list[tuple[int, int]]] = {}  # links → their ends
        self.refresh()

    def refresh(self) -> None:
        """Which links have a distance model (again, after a change of models)."""
        self.ranged: set[Link] = {link for link, m in self.links.models.items() if m.ranged}
        self.needed = bool(self.ranged) or self.links.air is not None  # the air's too
        out = self.links.out_links
        # The agents whose epoch position each kind of packet's decisions need.
        self._state_needs = {
            i: tuple(j for j in out[i] if ("formation", i, j) in self.ranged) for i in out
        }
        self._own_needs = {
            (kind, i): (i,) if link in self.ranged else ()
            for i in self.links.agents
            for kind, link in (
                ("report", ("report", i, LEADER_ENDPOINT)),
                ("estimate", ("estimate", LEADER_ENDPOINT, i)),
            )
        }

    @property
    def held(self) -> dict[int, list[Held]]:
        """The packets held, by epoch, in the order they were held."""
        out: dict[int, list[Held]] = {}
        seen: set[int] = set()
        for (epoch, _), waits in sorted(self._waits.items()):
            for wait in waits:
                if id(wait) not in seen:
                    seen.add(id(wait))
                    out.setdefault(epoch, []).append(wait.held)
        return out

    @property
    def ready(self) -> bool:
        """Whether held packets may be handed back now (:meth:`release`)."""
        return bool(self._ready)

    def admit(
        self, route: Route, epoch: int, seq: int, payload: Any, dead: Collection[int]
    ) -> bool:
        """Read a state's position; True when the packet can be decided now, else it is held.

        ``dead``: the senders not waited for at ``epoch``.
        """
        kind, source, target = route
        known = self.at.get(epoch)
        if kind == "state":
            if known is None:
                known = self.at[epoch] = {}
                self.at.pop(epoch - KEEP_EPOCHS, None)
            if source not in known:
                if type(payload) is not bytes:  # held as bytes: Zenoh's buffer goes back at once
                    payload = payload.to_bytes()
                pos = _position(payload)
                if pos is None:
                    self.malformed += 1
                known[source] = pos
                if (epoch, source) in self._waits:
                    self._ready.append((epoch, source))
            needs = self._state_needs.get(source, ())
        else:
            needs = self._own_needs.get((kind, source if kind == "report" else target), ())
        if not needs:
            return True
        if known is None:
            missing = [a for a in needs if a not in dead]
        else:
            missing = [a for a in needs if a not in known and a not in dead]
        if not missing:
            return True
        wait = _Wait((route, epoch, seq, payload), len(missing))
        waits = self._waits
        for a in missing:
            got = waits.get((epoch, a))
            if got is None:
                waits[(epoch, a)] = [wait]
            else:
                got.append(wait)
        return False

    def release(self, gone: int | None = None) -> Iterator[Held]:
        """The held packets that can be decided now: the positions they need read, or the
        agents they wait for down (``gone``: one just now)."""
        if gone is not None:
            self._ready += sorted(key for key in self._waits if key[1] == gone)
        ready, waits = self._ready, self._waits
        while ready:
            for wait in waits.pop(ready.pop(0), ()):
                wait.missing -= 1
                if wait.missing == 0:
                    yield wait.held

    def length(self, link: Link, epoch: int) -> float | None:
        """The length [m] of ``link`` at ``epoch`` if it has a distance model, else None.

        An end whose position is unreadable makes the link infinitely long (out of range).
        """
        if link not in self.ranged:
            return None
        return self._measure(link, self.at.get(epoch, {}))

    def lengths(self, links: tuple[Link, ...], epoch: int) -> list[float]:
        """The lengths [m] of formation ``links`` at ``epoch``, each what :meth:`length` gives:
        one by one for a few links, vectorised for many (:func:`link_lengths` and
        :func:`link_length` agree bit for bit)."""
        known = self.at.get(epoch, {})
        if len(links) < VECTOR_LINKS:
            pairs = self._pairs.get(links)
            if pairs is None:
                pairs = self._pairs[links] = [(src, dst) for _, src, dst in links]
            out = []
            for src, dst in pairs:
                a, b = known.get(src), known.get(dst)
                out.append(
                    math.inf if a is None or b is None or len(a) != len(b) else link_length(a, b)
                )
            return out
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
                return link_lengths(x[ends[0]], x[ends[1]]).tolist()  # type: ignore[no-any-return]
        return [self._measure(link, known) for link in links]

    def of_epoch(self, epoch: int) -> npt.NDArray[np.float64]:
        """(n, d) the agents' positions at ``epoch`` [m], row ``i − 1`` agent ``i``; NaN where
        not read (or unreadable)."""
        known = self.at.get(epoch, {})
        rows = [known.get(i) for i in self.links.agents]
        d = next((len(r) for r in rows if r is not None), len(self.access_point or ()) or 2)
        return np.array(
            [r if r is not None and len(r) == d else [math.nan] * d for r in rows],
            dtype=np.float64,
        )

    def _measure(self, link: Link, known: dict[int, list[float] | None]) -> float:
        _, src, dst = link
        a = self.access_point if src == LEADER_ENDPOINT else known.get(src)
        b = self.access_point if dst == LEADER_ENDPOINT else known.get(dst)
        if a is None or b is None or len(a) != len(b):
            return math.inf
        return link_length(a, b)


__all__ = ["KEEP_EPOCHS", "Held", "Positions"]
