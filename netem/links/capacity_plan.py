"""The simulator's capacity queues: a plan's queue verdicts, epoch by epoch (docs/model.md §9).

The same :class:`netem.links.capacity_network.CapacityNetwork` netem's lockstep judges its
packets with, fed the packets a plan's models passed, phase by phase in virtual time, so the
simulator drops what netem drops, bit for bit.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from formation.scenario import Scenario
from formation.wire_size import WireSizes
from netem.links.capacity import REASONS
from netem.links.capacity_network import PHASE_ORDER, network_of, packet_kind


class CapacityPlanner:
    """The queues of a plan, epoch by epoch: :func:`capacity_plan` at once, or the simulator's
    links that decide by their length, whose packets are known an epoch at a time."""

    def __init__(self, scenario: Scenario, links: npt.NDArray[np.int64]) -> None:
        self.net = network_of(scenario)
        self.sizes = WireSizes(scenario)
        self.pairs = [(int(a), int(b)) for a, b in links.tolist()]
        self.kinds = [packet_kind(lk) for lk in self.pairs]
        self.code = {name: k for k, name in enumerate(REASONS)}
        # per phase, the columns a queue serves (no queue changes in a plan: netem's are live)
        self.served = {
            phase: np.array(
                [
                    c
                    for c, lk in enumerate(self.pairs)
                    if self.kinds[c][0] == phase and self.net.constrained(lk)
                ],
                dtype=np.int64,
            )
            for phase in PHASE_ORDER
        }
        self.known: dict[tuple[int, int], int] = {}  # (column, digits of the epoch) → payload [B]

    def epoch(self, k: int, passed: npt.NDArray[np.bool_]) -> npt.NDArray[np.int8]:
        """Epoch ``k``'s verdicts (L,) for the packets ``passed`` (L,); epochs in order."""
        out = np.zeros(passed.shape, dtype=np.int8)
        digits = len(str(k))
        for phase, cols_all in self.served.items():
            cols = cols_all[passed[cols_all]].tolist() if cols_all.size else []
            if not cols:
                continue
            packets = []
            for c in cols:
                size = self.known.get((c, digits))
                if size is None:
                    kind, agent = self.kinds[c]
                    size = self.known[(c, digits)] = self.sizes.payload_bytes(kind, agent, k)
                packets.append((self.pairs[c], size))
            for c, v in zip(cols, self.net.phase(k, phase, packets), strict=True):
                if v.reason:
                    out[c] = self.code[v.reason]
        return out


def capacity_plan(
    scenario: Scenario, passed: npt.NDArray[np.bool_], links: npt.NDArray[np.int64]
) -> npt.NDArray[np.int8]:
    """Every epoch's queue verdicts, for packets the models passed.

    Parameters
    ----------
    scenario : with ``network.capacity``
    passed : (E, L) the models passed link ``l``'s packet of epoch ``k``
    links : (L, 2) ``(src, dst)`` of each column; ``0`` is the leader's end

    Returns
    -------
    (E, L) int8: an index into ``netem.links.capacity.REASONS`` (0 where the queues passed the
    packet in time or had none to judge).
    """
    planner = CapacityPlanner(scenario, links)
    out = np.zeros(passed.shape, dtype=np.int8)
    for k in range(passed.shape[0]):
        out[k] = planner.epoch(k, passed[k])
    return out


__all__ = ["CapacityPlanner", "capacity_plan"]
