"""The shared medium: frames on the air, which overlap which, who is locked onto what.

A frame on the air adds its power at every agent. An agent that is not sending and not
already receiving locks onto a frame whose preamble it detects (power and SINR at the
frame's start above the detection thresholds); when the frame ends, ``Reception`` decides
from every frame that overlapped it whether the agent decoded it. A later frame never takes
over a lock, as in ns-3 without a frame-capture model, so capture is a stronger first frame
surviving a weaker later one (docs/model.md §11). An agent that starts sending drops what it
was receiving (half duplex).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from netem.links.wifi.reception import Reception, Transmission

Floats = npt.NDArray[np.float64]
Bools = npt.NDArray[np.bool_]
ACK = -1  # a transmission's frame index when it is an ACK


@dataclass
class Medium:
    """What is on the air now, and which agent is locked onto which transmission."""

    power_mw: Floats  # (n, n) [i, j]: what j receives from i; 0 on the diagonal
    noise_mw: float
    detect_mw: float  # the power a preamble needs to be detected and decoded
    detect_snr: float  # linear
    energy_mw: float  # carrier sense: the sensed frames' summed power that holds it busy
    reception: Reception
    on_air: list[int] = field(default_factory=list)  # log indices
    lock: npt.NDArray[np.int64] = field(init=False)  # agent -> index in on_air's log, -1
    log: list[Transmission] = field(default_factory=list)

    sensed: npt.NDArray[np.bool_] = field(init=False)  # per log index
    # carrier sense changes only when a frame is sensed or ends: kept until then
    _carrier: Bools | None = field(init=False, default=None)

    def __post_init__(self) -> None:
        self.lock = np.full(self.power_mw.shape[0], -1, dtype=np.int64)
        self.sensed = np.zeros(64, dtype=bool)

    def sense(self, index: int) -> None:
        """Carrier sense sees transmission ``index`` from now on."""
        self.log[index].sensed = True
        self.sensed[index] = True
        self._carrier = None

    def total_mw(self) -> Floats:
        if not self.on_air:
            return np.zeros(self.power_mw.shape[0])
        senders = [self.log[i].sender for i in self.on_air]
        return np.asarray(self.power_mw[senders].sum(axis=0))

    def start(self, txs: list[Transmission], sending: Bools) -> list[int]:
        """Put ``txs`` (starting together) on the air; ``sending``: agents transmitting now,
        new senders included. Returns the log indices of the new transmissions."""
        first = len(self.log)
        self.log.extend(txs)
        if len(self.log) > self.sensed.shape[0]:
            self.sensed = np.concatenate([self.sensed, np.zeros_like(self.sensed)])
        new = list(range(first, len(self.log)))
        for i in self.on_air:
            self.log[i].overlaps.extend(new)
        for k, tx in enumerate(txs):
            tx.overlaps.extend(self.on_air)
            tx.overlaps.extend(new[:k] + new[k + 1 :])
        self.on_air.extend(new)
        for tx in txs:
            self.lock[tx.sender] = -1  # half duplex: a sender hears nothing
        self._carrier = None
        total = self.total_mw()
        free = (self.lock < 0) & ~sending
        if not free.any():
            return list(range(first, len(self.log)))
        powers = self.power_mw[[tx.sender for tx in txs]]  # (k, n)
        ok = (powers >= self.detect_mw) & (
            powers >= self.detect_snr * (self.noise_mw + total - powers)
        )
        ok &= free[None, :]
        best = np.where(ok, powers, -1.0).argmax(axis=0)
        hit = ok.any(axis=0)
        self.lock[hit] = first + best[hit]
        return list(range(first, len(self.log)))

    def end(self, index: int) -> tuple[Bools, Bools]:
        """Take transmission ``index`` off the air: (locked, received), each (n,)."""
        tx = self.log[index]
        self.on_air.remove(index)
        locked = self.lock == index
        received = np.zeros_like(locked)
        receivers = np.flatnonzero(locked)
        if receivers.shape[0]:
            others = [self.log[o] for o in tx.overlaps]
            received[receivers] = self.reception.decoded(index, tx, others, receivers)
        self.lock[locked] = -1
        self._carrier = None
        return locked, received

    def carrier_busy(self) -> Bools:
        """Agents whose carrier sense finds the medium busy: locked onto a sensed frame, or
        the sensed frames' energy above the carrier-sense threshold (``energy_mw``)."""
        if self._carrier is None:
            self._carrier = self._carrier_busy()
        return self._carrier

    def _carrier_busy(self) -> Bools:
        sensed = [self.log[i].sender for i in self.on_air if self.log[i].sensed]
        n = self.power_mw.shape[0]
        if not sensed:
            return np.zeros(n, dtype=bool)
        energy = self.power_mw[sensed].sum(axis=0)
        locked = (self.lock >= 0) & self.sensed[np.maximum(self.lock, 0)]
        return np.asarray((energy >= self.energy_mw) | locked)


__all__ = ["ACK", "Medium"]
