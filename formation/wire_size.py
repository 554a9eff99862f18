"""How many bytes a run's packets take on the wire, as a capacity queue counts them.

netem and the simulator must put the same sizes through the same queues to drop the same
packets, bit for bit (``formation.capacity``). A packet's exact bytes depend on what neither
can know ahead alike: the sender's monotonic stamp, the run id, how many digits each float
happens to print with, the substitutions of the epoch before (which follow from the
strategy). So both take a packet's size as its message's **nominal size**: the message the
sender would send in an epoch where nothing was lost, built with the wire models of
:mod:`formation.messages` and encoded by :mod:`formation.codec`, with every float
:data:`NOMINAL_FLOAT` wide (19 characters: a position of metres to the last bit), a
:data:`NOMINAL_RUN_ID` and a 19-digit stamp. It depends only on the kind, the sender's or
receiver's neighbours, the dimension and dynamics, and the digits of the epoch.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from formation.codec import encode
from formation.messages import (
    AgentEstimate,
    CoordinationState,
    Measurement,
    TokenReport,
)
from formation.scenario import Scenario

Kind = Literal["state", "report", "estimate"]
NOMINAL_FLOAT = -12.345678901234567  # [m] repr is 19 characters
NOMINAL_RUN_ID = "r" * 32
NOMINAL_STAMP_NS = 10**18  # 19 digits: a monotonic clock of 32 years
_POWERS_OF_TEN = 10 ** np.arange(1, 19, dtype=np.int64)  # the epochs that gain a digit


class WireSizes:
    """Nominal payload sizes [B] of one scenario's packets, memoised by kind, agent and epoch digits."""

    def __init__(self, scenario: Scenario) -> None:
        self.scenario = scenario
        self._known: dict[tuple[Kind, int, int], int] = {}

    def payload_bytes(self, kind: Kind, agent: int, epoch: int) -> int:
        """The nominal size of agent ``agent``'s ``kind`` packet of ``epoch`` [B].

        ``state``: agent ``agent``'s state (the same on each of its out-links); ``report``:
        its report to the leader; ``estimate``: the leader's estimate for it.
        """
        digits = len(str(epoch))
        key = (kind, agent, digits)
        size = self._known.get(key)
        if size is None:
            size = self._known[key] = len(encode(self._message(kind, agent, 10 ** (digits - 1))))
        return size

    def payload_bytes_of(
        self, kind: Kind, agent: int, epochs: npt.NDArray[np.int64]
    ) -> npt.NDArray[np.int64]:
        """:meth:`payload_bytes` of each of ``epochs`` (non-negative), at once [B]."""
        digits = 1 + np.searchsorted(_POWERS_OF_TEN, epochs, side="right")
        known, where = np.unique(digits, return_inverse=True)
        sizes = [self.payload_bytes(kind, agent, 10 ** (int(k) - 1)) for k in known]
        return np.asarray(sizes, dtype=np.int64)[where]

    def _message(
        self, kind: Kind, agent: int, epoch: int
    ) -> CoordinationState | TokenReport | AgentEstimate:
        s = self.scenario
        vec = [NOMINAL_FLOAT] * s.dimension
        neighbours = s.in_neighbours[agent - 1]
        head: dict[str, Any] = {
            "run_id": NOMINAL_RUN_ID,
            "seq": epoch,
            "epoch": epoch,
            "stamp_ns": NOMINAL_STAMP_NS,
        }
        if kind == "state":
            unicycle = s.control.dynamics == "unicycle"
            return CoordinationState(
                **head,
                sender=f"agent/{agent}",
                agent=agent,
                position=vec,
                velocity=vec if s.control.dynamics == "double" else None,
                heading=NOMINAL_FLOAT if unicycle else None,
                saturated=0 if unicycle else None,
            )
        if kind == "report":
            return TokenReport(
                **head,
                sender=f"agent/{agent}",
                agent=agent,
                measurements=[Measurement(neighbour=j, token=1, z=vec) for j in neighbours],
            )
        return AgentEstimate(
            **head,
            sender="leader",
            agent=agent,
            neighbours=neighbours,
            positions=[vec for _ in neighbours],
            v_ref=vec,
        )


__all__ = ["NOMINAL_FLOAT", "NOMINAL_RUN_ID", "NOMINAL_STAMP_NS", "Kind", "WireSizes"]
