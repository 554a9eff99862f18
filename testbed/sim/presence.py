"""The scenario's events over a batch's flattened links (issue 20, ``formation.events``).

What netem and the agent processes do with a :class:`formation.events.Membership`, as masks
the simulator's epoch loop (``testbed.sim.batch``) applies: a packet goes out only between
two agents taking part; a receiver's consensus runs over its in-links whose sender is in the
formation graph (a crashed sender's packets are lost there, a left one's edge is gone); an
agent out of the team stays where it is; a (re)started agent's process begins at rest with no
memory of its links and no known ``v_ref``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from agent import LinkMemory
from analysis import team_edges
from formation.events import Membership

Array = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]
Ints = npt.NDArray[np.int64]


@dataclass(frozen=True)
class Presence:
    """A membership over the ``L`` directed links of each of ``size`` members.

    present : (E + 1, n) the agent takes part; link_on : (E + 1, L) both ends take part
    (a packet is sent and decided); link_in : (E + 1, L) the receiver takes part and the
    sender is in the graph (the link enters its consensus); starts : (E + 1, n) a process
    begins (join, restart)
    """

    present: Mask
    link_on: Mask
    link_in: Mask
    starts: Mask
    dst: Ints
    size: int

    @classmethod
    def of(cls, team: Membership | None, src: Ints, dst: Ints, size: int) -> Presence | None:
        """None when everybody takes part throughout (nothing to apply)."""
        if team is None or team.everyone:
            return None
        p = team.present
        link_on = team_edges(p, np.stack([src, dst], axis=1))
        return cls(p, link_on, team.in_graph[:, src - 1] & p[:, dst - 1], team.starts, dst, size)

    def rows(self, k: int) -> Ints | None:
        """Flattened rows (``b·L + l``) of the links in the consensus at epoch ``k``; None: all."""
        on = self.link_in[k]
        return None if on.all() else np.flatnonzero(np.tile(on, self.size))

    def landing(self, k: int, flat: Ints, sent: Ints) -> Mask:
        """Which delayed packets landing at ``k`` (flat rows, sent epochs) reach their receiver:
        sent between two agents taking part, and the receiver takes part at ``k``."""
        link = flat % self.dst.size
        reached: Mask = self.link_on[sent, link] & self.present[k, self.dst[link] - 1]
        return reached

    def restart(self, k: int, memory: LinkMemory, v_known: Array) -> LinkMemory:
        """Agents whose process starts at ``k`` forget their links and ``v_ref`` (in place)."""
        new = self.starts[k]
        if not new.any():
            return memory
        v_known[:, new] = 0.0
        return memory.forget(np.tile(new[self.dst - 1], self.size))


__all__ = ["Presence"]
