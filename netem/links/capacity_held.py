"""Realtime capacity queues: the packets each queue holds until they leave (docs/model.md §9).

Realtime netem decides a packet's departure as it comes, and holds it until then. A full
``oldest`` queue pushes out a packet it holds (:func:`netem.links.capacity.make_room`); the
link time that packet was given goes back to the packets behind it, served anew from the
queue's clock and bucket before them, as :func:`netem.links.capacity.serve_packets` serves
them when it knows every arrival at once. A packet whose departure from one queue changes
arrives that much earlier at its next, which serves it and those behind it anew in turn;
a packet whose departure from its last queue changed is :attr:`HeldQueues.retimed`.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

from netem.links.capacity import QueueParams, QueueState, Served, serve_packets


@dataclass(slots=True)
class Held:
    """A packet a queue holds: its token, arrival [s], size [B] and departure [s], and the
    queue's bucket once it left [B]."""

    token: int
    arrival_s: float
    size: int
    departure_s: float
    tokens_after: float


class HeldQueues:
    """Each queue's held packets in its order, and its clock and bucket before them."""

    def __init__(self, params: Sequence[QueueParams]) -> None:
        self.params = params  # the network's, changed in place as a queue's change
        self.held: dict[int, deque[Held]] = {}
        self.base: dict[int, tuple[float, float]] = {}  # (clock [s], bucket [B])
        self.route: dict[int, tuple[int, ...]] = {}  # a passed packet's queues, until it left
        self.retimed: dict[int, float] = {}  # token → its new departure from its last queue [s]

    def settle(self, k: int, now_s: float) -> None:
        """Queue ``k`` lets go of the packets that left it by ``now_s``."""
        held = self.held.get(k)
        while held and held[0].departure_s <= now_s:
            h = held.popleft()
            self.base[k] = (h.departure_s, h.tokens_after)
            route = self.route.get(h.token)
            if route is not None and route[-1] == k:
                del self.route[h.token]

    def state(self, k: int) -> QueueState:
        """Queue ``k`` as :func:`serve_packets` takes it: its held packets as the backlog."""
        held = self.held.get(k)
        if not held:
            return QueueState(*self.base.get(k, (-math.inf, math.inf)))
        last = held[-1]
        return QueueState(
            last.departure_s,
            last.tokens_after,
            tuple(h.departure_s for h in held),
            tuple(h.size for h in held),
        )

    def tokens(self, k: int, positions: list[int]) -> list[int]:
        held = self.held[k]
        return [held[j].token for j in positions]

    def add(self, k: int, token: int, arrival_s: float, size: int, run: Served) -> None:
        """A packet queue ``k`` passed (``run``: :func:`serve_packets` of it alone)."""
        held = self.held.setdefault(k, deque())
        held.append(Held(token, arrival_s, size, run.departure_s[0], run.state.tokens_bytes))

    def remove(self, tokens: list[int], now_s: float) -> None:
        """The packets ``tokens``, pushed out at ``now_s``, leave every queue that still holds
        them then; each serves the packets behind them anew. A queue one of them left before
        (an earlier stage of its route) keeps it: it took its time there."""
        gone = set(tokens)
        for token in tokens:
            self.route.pop(token, None)
            self.retimed.pop(token, None)
        for k, held in self.held.items():
            positions = [j for j, h in enumerate(held) if h.token in gone and h.departure_s > now_s]
            if not positions:
                continue
            first = positions[0]
            head = next(j for j, h in enumerate(held) if h.departure_s > now_s)
            # the head pushed out: the one behind it is the head, and may leave, from now on
            ready = now_s if first == head and held[first].arrival_s <= now_s else -math.inf
            for j in reversed(positions):
                del held[j]
            self._serve_from(k, first, ready)

    def _serve_from(self, k: int, first: int, ready_s: float) -> None:
        """Queue ``k`` serves its held packets from position ``first`` on anew, the first no
        earlier than ``ready_s``; a changed departure moves the packet's next arrival."""
        held = self.held[k]
        if first >= len(held):
            return
        params = self.params[k]
        if first:
            clock, bucket = held[first - 1].departure_s, held[first - 1].tokens_after
        else:
            clock, bucket = self.base.get(k, (-math.inf, math.inf))
        moved: list[Held] = []
        for j in range(first, len(held)):
            h = held[j]
            run = serve_packets(
                params, [h.arrival_s], [h.size], state=QueueState(clock, bucket), ready_s=ready_s
            )
            ready_s = -math.inf
            clock, bucket = run.departure_s[0], run.state.tokens_bytes
            if clock != h.departure_s:
                moved.append(h)
            h.departure_s, h.tokens_after = clock, bucket
        for h in moved:
            route = self.route.get(h.token)
            if route is None:
                continue  # dropped by a later queue, or gone
            at = route.index(k)
            if at == len(route) - 1:
                self.retimed[h.token] = h.departure_s
                continue
            nxt = route[at + 1]
            later = self.held.get(nxt, deque())
            at = next((i for i, g in enumerate(later) if g.token == h.token), -1)
            if at >= 0:
                later[at].arrival_s = h.departure_s
                self._serve_from(nxt, at, -math.inf)


__all__ = ["Held", "HeldQueues"]
