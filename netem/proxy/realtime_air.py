"""Realtime: packets on the shared air, each held until its computed arrival.

In realtime the agents' own timing is the air's: a packet is ready when it reaches netem. A
phase's packets (its epoch and kind, ``netem.links.air_network``) are decided together by
the model from the first one's arrival, and again at the next settle after others came (once
for all that came since, not once a packet), and a packet is settled once no later one can
change its fate: delivered when the model's arrival has passed (a later frame is ready now,
so it starts after DIFS, after that arrival), dropped when the phase's deadline has. Packets
are ready no earlier than the last settle, so what is settled stays so. Each decision sorts
the phase's delivered packets by arrival, so a settle takes only those due and the next
settle time is the first of them: the work is the packets' count, not its square. A
delivered packet goes out at its model's arrival (netem's lag behind it is counted,
:attr:`RealtimeAir.lag_ns`), one past the deadline is ``late``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import orjson

from netem.links.air_network import AirNetwork, AirVerdict
from netem.links.wifi import load_compiled_loop
from netem.proxy.routes import Phase

Link = tuple[int, int]


@dataclass
class _Phase:
    """One (epoch, phase)'s packets on the air: when its first came, each one's link, when
    it came [ns from the first], what the caller keeps with it, which are settled, and the
    delivered ones not settled yet, latest arrival first [wall ns]."""

    origin_ns: int
    deadline_ns: int
    links: list[Link] = field(default_factory=list)
    ready_ns: list[int] = field(default_factory=list)
    items: list[Any] = field(default_factory=list)
    verdicts: list[AirVerdict] = field(default_factory=list)
    settled: list[bool] = field(default_factory=list)
    due: list[tuple[int, int]] = field(default_factory=list)  # (arrival, index)
    decided: bool = False  # no packet came since the last decision

    def arrival_ns(self, v: AirVerdict) -> int:
        return self.origin_ns + (0 if math.isnan(v.arrival_ms) else round(v.arrival_ms * 1e6))


class RealtimeAir:
    """The phases on the air not yet settled, and the agents' positions read from states."""

    def __init__(self, net: AirNetwork) -> None:
        self.net = net
        load_compiled_loop()  # before the run, not while its first packets wait
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
        got.settled.append(False)
        got.decided = False

    def settle(self, now_ns: int) -> list[tuple[Any, AirVerdict, int]]:
        """The packets whose fate is known by ``now_ns``: (item, verdict, when it arrives
        [wall ns]; for a drop, now)."""
        self.settled_ns = now_ns
        out: list[tuple[Any, AirVerdict, int]] = []
        for key in list(self.open):
            ph = self.open[key]
            if not ph.decided:
                self._decide(key, ph)
            if now_ns >= ph.deadline_ns:
                for i, v in enumerate(ph.verdicts):
                    if not ph.settled[i]:
                        out.append((ph.items[i], v, ph.arrival_ns(v) if v.passed else now_ns))
                del self.open[key]
                continue
            while ph.due and ph.due[-1][0] <= now_ns:
                at, i = ph.due.pop()
                ph.settled[i] = True
                out.append((ph.items[i], ph.verdicts[i], at))
        return out

    def next_ns(self) -> int | None:
        """When the next packet may settle [wall ns] (None: nothing open)."""
        times = []
        for ph in self.open.values():
            if not ph.decided:
                return 0  # to decide now
            times.append(ph.deadline_ns)
            if ph.due:
                times.append(ph.due[-1][0])
        return min(times) if times else None

    def _decide(self, key: tuple[int, Phase], ph: _Phase) -> None:
        """The phase's packets decided together; its delivered ones not yet settled, sorted."""
        epoch, phase = key
        ph.verdicts = self.net.phase(
            epoch,
            phase,
            ph.links,
            self._positions(epoch),
            ph.ready_ns,
            ph.deadline_ns - ph.origin_ns,
        )
        due = [
            (ph.arrival_ns(v), i)
            for i, v in enumerate(ph.verdicts)
            if v.passed and not ph.settled[i]
        ]
        ph.due = sorted(due, reverse=True)
        ph.decided = True

    def _positions(self, epoch: int) -> np.ndarray:
        known = self.positions.get(epoch) or self.positions.get(epoch - 1, {})
        d = self.dimension or 2
        return np.array(
            [known.get(i, [math.nan] * d) for i in range(1, self.net.n + 1)], dtype=np.float64
        )


__all__ = ["RealtimeAir"]
