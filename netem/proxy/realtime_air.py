"""Realtime: packets on the shared air, each held until its computed arrival.

In realtime the agents' own timing is the air's: a packet is ready when it reaches netem. A
phase's packets (its epoch and kind, ``netem.links.air_network``) are decided together by
the model from the first one's arrival, again whenever another comes, and a packet is
settled once no later one can change its fate: delivered when the model's arrival has
passed (a later frame is ready now, so it starts after DIFS, after that arrival), dropped
when the phase's deadline has. Packets are ready no earlier than the last settle, so what
is settled stays so. A delivered packet goes out at its model's arrival (netem's lag
behind it is counted, :attr:`RealtimeAir.lag_ns`), one past the deadline is ``late``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import orjson

from netem.links.air_network import AirNetwork, AirVerdict
from netem.proxy.routes import Phase

Link = tuple[int, int]


@dataclass
class _Phase:
    """One (epoch, phase)'s packets on the air: when its first came, each one's link, when
    it came [ns from the first], what the caller keeps with it, and which are settled."""

    origin_ns: int
    deadline_ns: int
    links: list[Link] = field(default_factory=list)
    ready_ns: list[int] = field(default_factory=list)
    items: list[Any] = field(default_factory=list)
    verdicts: list[AirVerdict] = field(default_factory=list)
    settled: set[int] = field(default_factory=set)


class RealtimeAir:
    """The phases on the air not yet settled, and the agents' positions read from states."""

    def __init__(self, net: AirNetwork) -> None:
        self.net = net
        self.open: dict[tuple[int, Phase], _Phase] = {}
        self.positions: dict[int, dict[int, list[float]]] = {}  # epoch → agent → [m]
        self.dimension = 0 if net.access_point is None else int(net.access_point.shape[0])
        self.settled_ns = 0  # [ns] nothing comes earlier than this any more
        self.lag_ns: list[int] = []  # how late netem put out each delivered packet

    def carries(self, link: Link) -> bool:
        return self.net.carries(link)

    def read_position(self, epoch: int, agent: int, payload: bytes) -> None:
        """A state's ``position``, for its epoch's phases."""
        try:
            pos = orjson.loads(payload).get("position")
        except (orjson.JSONDecodeError, AttributeError):
            return
        if isinstance(pos, list) and pos and all(isinstance(v, (int, float)) for v in pos):
            self.positions.setdefault(epoch, {})[agent] = [float(v) for v in pos]
            self.dimension = self.dimension or len(pos)
            self.positions.pop(epoch - 64, None)

    def add(
        self, epoch: int, phase: Phase, link: Link, came_ns: int, deadline_ns: int, item: Any
    ) -> None:
        """A packet the models passed, which reached netem at ``came_ns`` [wall ns]."""
        got = self.open.get((epoch, phase))
        came_ns = max(came_ns, self.settled_ns)
        if got is None:
            got = self.open[(epoch, phase)] = _Phase(came_ns, deadline_ns)
        got.links.append(link)
        got.ready_ns.append(max(0, came_ns - got.origin_ns))
        got.items.append(item)
        got.verdicts = []  # to decide again

    def settle(self, now_ns: int) -> list[tuple[Any, AirVerdict, int]]:
        """The packets whose fate is known by ``now_ns``: (item, verdict, when it arrives
        [wall ns]; for a drop, now)."""
        self.settled_ns = now_ns
        out: list[tuple[Any, AirVerdict, int]] = []
        for key in list(self.open):
            ph = self.open[key]
            if not ph.verdicts:
                ph.verdicts = self.net.phase(
                    key[0],
                    key[1],
                    ph.links,
                    self._positions(key[0]),
                    ph.ready_ns,
                    ph.deadline_ns - ph.origin_ns,
                )
            over = now_ns >= ph.deadline_ns
            for i, v in enumerate(ph.verdicts):
                if i in ph.settled:
                    continue
                at = ph.origin_ns + (0 if math.isnan(v.arrival_ms) else round(v.arrival_ms * 1e6))
                if (v.passed and at <= now_ns) or over:
                    ph.settled.add(i)
                    out.append((ph.items[i], v, at if v.passed else now_ns))
            if over:
                del self.open[key]
        return out

    def next_ns(self) -> int | None:
        """When the next packet may settle [wall ns] (None: nothing open)."""
        times = []
        for ph in self.open.values():
            times.append(ph.deadline_ns)
            for i, v in enumerate(ph.verdicts):
                if i not in ph.settled and v.passed:
                    times.append(ph.origin_ns + round(v.arrival_ms * 1e6))
            if not ph.verdicts:
                return 0  # to decide now
        return min(times) if times else None

    def _positions(self, epoch: int) -> np.ndarray:
        known = self.positions.get(epoch) or self.positions.get(epoch - 1, {})
        d = self.dimension or 2
        return np.array(
            [known.get(i, [math.nan] * d) for i in range(1, self.net.n + 1)], dtype=np.float64
        )


__all__ = ["RealtimeAir"]
