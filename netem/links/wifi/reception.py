"""Whether a receiver locked onto a frame decodes it, from the interference it met.

The frame's time on the air is cut wherever another transmission starts or ends; over each
piece the interference at a receiver is the sum of the other frames' powers. With
``error_model = "chunks"`` (as ns-3.44's ``InterferenceHelper``) each piece of the PHY header
and of the payload is a chunk of ``rate × duration`` bits at its SINR, decoded with the chunk
success rate of ``error_rate``; the frame is decoded with the product, by a keyed uniform draw
of ``(seed, AIR_STREAM, 2, epoch, phase, transmission, receiver)``. With ``"threshold"`` it is
decoded when its SINR over the *largest* interference reaches the rate's threshold
(docs/model.md §11).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from formation.keyed_random import keyed_uniform
from netem.links.wifi.error_rate import chunk_success
from netem.links.wifi.phy import Phy
from netem.links.wifi.radio import AIR_STREAM

Floats = npt.NDArray[np.float64]
Ints = npt.NDArray[np.int64]
Bools = npt.NDArray[np.bool_]
RECEPTION = 2  # sub-stream of AIR_STREAM (0: backoffs, 1: shadowing)


@dataclass
class Transmission:
    sender: int
    frame: int  # the data frame's index, or ACK
    dest: int  # BROADCAST, the data's receiver, or (ACK) the data's sender
    start_ns: int
    end_ns: int
    rate_kbps: int  # the payload's
    sinr_needed: float  # linear, for the threshold model
    overlaps: list[int] = field(default_factory=list)  # log indices of overlapping frames
    sensed: bool = False  # by carrier sense, from start_ns + aCCATime


@dataclass
class Reception:
    """Decides reception at locked receivers; one per phase."""

    power_mw: Floats  # (n, n) [i, j]: what j receives from i
    noise_mw: float
    phy: Phy
    chunks: bool  # the chunk error model, else the SINR threshold
    key: tuple[int, int, int]  # (seed, epoch, phase)
    _alone: dict[tuple[int, int], Floats] = field(default_factory=dict)

    def decoded(
        self, index: int, tx: Transmission, others: list[Transmission], receivers: Ints
    ) -> Bools:
        """Which of ``receivers`` decode transmission ``index``; ``others`` overlap it."""
        signal = self.power_mw[tx.sender, receivers]
        if not self.chunks:
            worst = self._pieces(tx, others, receivers)[1].max(axis=0)
            return np.asarray(signal >= tx.sinr_needed * (self.noise_mw + worst))
        if others:
            bounds, interference = self._pieces(tx, others, receivers)
            p = self._success(tx, bounds, signal / (self.noise_mw + interference))
        else:
            p = self._alone_success(tx)[tx.sender, receivers]
        if (p >= 1.0).all():
            return np.ones(receivers.shape[0], dtype=bool)
        seed, epoch, phase = self.key
        u = keyed_uniform(seed, AIR_STREAM, RECEPTION, epoch, phase, index, receivers)
        return np.asarray(u < p)

    def _pieces(
        self, tx: Transmission, others: list[Transmission], receivers: Ints
    ) -> tuple[Ints, Floats]:
        """The times the interference changes (k + 1,) and the interference over each piece
        at each receiver (k, r) [mW]."""
        start, end = tx.start_ns, tx.end_ns
        if not others:
            return np.array([start, end], dtype=np.int64), np.zeros((1, receivers.shape[0]))
        o_start = np.array([max(o.start_ns, start) for o in others], dtype=np.int64)
        o_end = np.array([min(o.end_ns, end) for o in others], dtype=np.int64)
        bounds = np.unique(np.concatenate([[start, end], o_start, o_end]))
        on = (o_start[None, :] <= bounds[:-1, None]) & (bounds[:-1, None] < o_end[None, :])
        rows = self.power_mw[[o.sender for o in others]][:, receivers]
        return bounds, on.astype(np.float64) @ rows

    def _success(self, tx: Transmission, bounds: Ints, snr: Floats) -> Floats:
        """The product of the chunk success rates over the header and the payload (r,)."""
        phy, start = self.phy, tx.start_ns
        header_from, header_to = phy.header_window_ns
        p = np.ones(snr.shape[1])
        for lo, hi, rate in (
            (start + header_from, start + header_to, phy.header_kbps),
            (start + phy.preamble_ns, tx.end_ns, tx.rate_kbps),
        ):
            span = np.minimum(bounds[1:], hi) - np.maximum(bounds[:-1], lo)
            chunks = np.flatnonzero(span > 0)
            if chunks.shape[0] == 0:
                continue
            nbits = span[chunks] * rate // 1_000_000
            rates = chunk_success(phy.ofdm, rate, snr[chunks], nbits[:, None])
            p *= rates.prod(axis=0)
        return p

    def _alone_success(self, tx: Transmission) -> Floats:
        """(n, n): the chance a frame of this rate and length is decoded with no interference."""
        cache = (tx.rate_kbps, tx.end_ns - tx.start_ns)
        if cache not in self._alone:
            snr = self.power_mw / self.noise_mw
            bounds = np.array([tx.start_ns, tx.end_ns], dtype=np.int64)
            n = snr.shape[0]
            flat = self._success(tx, bounds, snr.reshape(1, n * n))
            self._alone[cache] = flat.reshape(n, n)
        return self._alone[cache]


__all__ = ["RECEPTION", "Reception", "Transmission"]
