"""Saturation throughput: Bianchi's analytical model and the same channel run by the air model.

G. Bianchi, "Performance analysis of the IEEE 802.11 distributed coordination function",
IEEE JSAC 18(3), 2000, basic access. Each of ``n`` stations always has a frame; it sends in a
slot with probability ``τ`` and a sent frame collides with probability ``p``:

    τ = 2 (1 − 2p) / ((1 − 2p)(W + 1) + p W (1 − (2p)^m)),   p = 1 − (1 − τ)^(n − 1)

(eqs. 7 and 9), ``W = CWmin + 1``, ``m = log2((CWmax + 1) / W)``. With
``P_tr = 1 − (1 − τ)^n`` and ``P_s = n τ (1 − τ)^(n − 1) / P_tr`` the throughput is

    S = P_s P_tr L / ((1 − P_tr) σ + P_tr P_s T_s + P_tr (1 − P_s) T_c)     (eq. 13)

with ``T_s = DATA + SIFS + ACK + DIFS`` and ``T_c = DATA + DIFS`` (eq. 14, no propagation
delay): the stations that did not send sense only energy during a collision and resume after
DIFS. The model assumes no retry limit; :func:`simulated_throughput` sets one out of reach.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from scipy.optimize import brentq

from netem.links.wifi.config import AirConfig
from netem.links.wifi.dcf import Key, decide_phase
from netem.links.wifi.frames import Frames

UNREACHED_RETRY_LIMIT = 10_000


def bianchi_tau(n: int, w: int, m: int) -> tuple[float, float]:
    """``(τ, p)``: the fixed point of eqs. 7 and 9 for ``n`` stations."""

    def gap(tau: float) -> float:
        p = 1.0 - (1.0 - tau) ** (n - 1)
        return tau - 2 * (1 - 2 * p) / ((1 - 2 * p) * (w + 1) + p * w * (1 - (2 * p) ** m))

    tau = float(brentq(gap, 1e-12, 1.0 - 1e-12, xtol=1e-15))
    return tau, 1.0 - (1.0 - tau) ** (n - 1)


def bianchi_throughput_bps(config: AirConfig, n: int, payload_bytes: int) -> float:
    """Bianchi's saturation throughput of ``n`` stations [bit/s] (eq. 13)."""
    phy, rate = config.physical, config.rate_kbps
    cw_min, cw_max = config.window
    w = cw_min + 1
    tau, _ = bianchi_tau(n, w, round(math.log2((cw_max + 1) / w)))
    p_tr = 1.0 - (1.0 - tau) ** n
    p_s = n * tau * (1.0 - tau) ** (n - 1) / p_tr
    data = phy.airtime_ns(payload_bytes + config.mac_overhead_bytes, rate)
    t_s = data + phy.sifs_ns + phy.ack_ns(rate) + phy.difs_ns
    t_c = data + phy.difs_ns
    slot_mean_ns = (1 - p_tr) * phy.slot_ns + p_tr * p_s * t_s + p_tr * (1 - p_s) * t_c
    return p_s * p_tr * 8 * payload_bytes / slot_mean_ns * 1e9


def saturated_phase(
    n: int, payload_bytes: int, frames_per_station: int
) -> tuple[npt.NDArray[np.float64], Frames]:
    """``n`` saturated stations within a metre of each other (every pair hears the others at
    one power: no frame outweighs another, though the chunk error model may still decode one
    at 0 dB), each with ``frames_per_station`` frames to its neighbour, all ready at once:
    positions (n, 2) [m] and frames."""
    angle = 2 * np.pi * np.arange(n) / n
    positions = 0.4 * np.column_stack([np.cos(angle), np.sin(angle)])
    sender = np.repeat(np.arange(n), frames_per_station)
    return positions, Frames.of(sender, (sender + 1) % n, payload_bytes, 0)


def throughput_bps(
    arrival_ns: npt.NDArray[np.int64], sender: npt.NDArray[np.int64], payload_bytes: int
) -> float:
    """The delivered frames' throughput [bit/s], from the tenth of them delivered first to the
    moment the first station has all its frames delivered (beyond it, fewer contend).
    ``arrival_ns`` (m,): each frame's arrival at its receiver, −1 if it was lost."""
    got = arrival_ns >= 0
    arrival, by = arrival_ns[got], sender[got]
    end = min(int(arrival[by == s].max()) for s in np.unique(sender))
    start = int(np.sort(arrival)[arrival.shape[0] // 10])
    counted = int(((arrival > start) & (arrival <= end)).sum())
    return counted * 8 * payload_bytes / (end - start) * 1e9


def simulated_throughput_bps(
    config: AirConfig, n: int, payload_bytes: int, frames_per_station: int, seed: int
) -> float:
    """The air model's throughput of ``n`` saturated stations [bit/s] (``saturated_phase``,
    ``throughput_bps``)."""
    positions, frames = saturated_phase(n, payload_bytes, frames_per_station)
    unbounded = config.model_copy(update={"retry_limit": UNREACHED_RETRY_LIMIT})
    outcome = decide_phase(unbounded, positions, frames, Key(seed, 0, 0))
    arrival = outcome.arrival_ns[np.arange(len(frames)), frames.receiver]
    return throughput_bps(arrival, frames.sender, payload_bytes)


__all__ = [
    "bianchi_tau",
    "bianchi_throughput_bps",
    "saturated_phase",
    "simulated_throughput_bps",
    "throughput_bps",
]
