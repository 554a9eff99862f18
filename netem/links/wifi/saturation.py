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
DIFS. The model assumes no retry limit; :func:`saturated_run` sets one out of reach.

Bianchi's chain lets a busy slot count down every waiting station's backoff, so a station
left at 1 sends in the first slot after the busy period. Under the standard's rules (as in
ns-3 and the air model) a busy slot counts for no one: the first slot after a success is open
only to its sender, if it draws 0. ns-3 validates its DCF against eq. 13 corrected for that
rule (:func:`bianchi_ns3_reference_bps`, docs/model.md §11).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

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
    tau, _ = bianchi_tau(n, *backoff_stages(config))
    slot, t_s, t_c = _slot_times_ns(config, payload_bytes)
    return _eq13_bps(n, tau, 8 * payload_bytes, slot, t_s, t_c)


def _eq13_bps(
    n: int, tau: float, bits: float, slot_ns: float, t_s_ns: float, t_c_ns: float
) -> float:
    """Eq. 13 [bit/s], ``bits`` delivered a success."""
    p_tr = 1.0 - (1.0 - tau) ** n
    p_s = n * tau * (1.0 - tau) ** (n - 1) / p_tr
    slot_mean_ns = (1 - p_tr) * slot_ns + p_tr * p_s * t_s_ns + p_tr * (1 - p_s) * t_c_ns
    return p_s * p_tr * bits / slot_mean_ns * 1e9


def _slot_times_ns(config: AirConfig, payload_bytes: int) -> tuple[int, int, int]:
    """``(σ, T_s, T_c)`` [ns] of eq. 14, basic access, no propagation delay."""
    phy, rate = config.physical, config.rate_kbps
    data = phy.airtime_ns(payload_bytes + config.mac_overhead_bytes, rate)
    return phy.slot_ns, data + phy.sifs_ns + phy.ack_ns(rate) + phy.difs_ns, data + phy.difs_ns


def backoff_stages(config: AirConfig) -> tuple[int, int]:
    """``(W, m)``: the first window and the number of doublings to CWmax."""
    cw_min, cw_max = config.window
    w = cw_min + 1
    return w, round(math.log2((cw_max + 1) / w))


def bianchi_ns3_reference_bps(
    config: AirConfig, n: int, payload_bytes: int, tau: float | None = None
) -> float:
    """Bianchi's throughput as ns-3 validates its DCF against it [bit/s]: eq. 13 with the
    slot after a success open only to its sender.

    With ``B = 1 / W`` a success is followed by the same station's, no one contending, with
    probability ``B``, and every success by one idle slot no other station sends in:

        E[P] = L / (1 − B),   T_S = T_s / (1 − B) + σ,   T_c = DATA + DIFS,
        S = P_s P_tr E[P] / ((1 − P_tr) σ + P_tr P_s T_S + P_tr (1 − P_s) T_c)

    with ``τ`` Bianchi's fixed point (eqs. 7 and 9) unless given (docs/model.md §11). Source:
    ns-3, ``src/wifi/examples/reference/Bianchi11a.m`` (L. Lanante, H. Yin, S. Deronne,
    University of Washington, 2020, BSD-3-Clause), "TC with DIFS", whose tables
    ``src/wifi/examples/wifi-bianchi.cc`` compares ns-3's saturation throughput with; there
    ``τ`` is eq. 7's value at the point of a grid of 10^4 on [0, 1] nearest the fixed point.
    """
    w, m = backoff_stages(config)
    if tau is None:
        tau, _ = bianchi_tau(n, w, m)
    slot, t_s, t_c = _slot_times_ns(config, payload_bytes)
    b = 1.0 / w
    return _eq13_bps(n, tau, 8 * payload_bytes / (1 - b), slot, t_s / (1 - b) + slot, t_c)


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
    start, end = steady_window_ns(arrival_ns, sender)
    counted = int(((arrival_ns > start) & (arrival_ns <= end)).sum())
    return counted * 8 * payload_bytes / (end - start) * 1e9


def steady_window_ns(
    arrival_ns: npt.NDArray[np.int64], sender: npt.NDArray[np.int64]
) -> tuple[int, int]:
    """``(start, end)`` [ns]: the tenth delivered frame's arrival and the moment the first
    station has all its frames delivered."""
    got = arrival_ns >= 0
    arrival, by = arrival_ns[got], sender[got]
    end = min(int(arrival[by == s].max()) for s in np.unique(sender))
    return int(np.sort(arrival)[arrival.shape[0] // 10]), end


@dataclass(frozen=True)
class SaturatedRun:
    """One saturated phase through the air model, over ``throughput_bps``'s window."""

    throughput_bps: float
    p_collision: float  # the delivered frames' failed attempts over their attempts


def saturated_run(
    config: AirConfig, n: int, payload_bytes: int, frames_per_station: int, seed: int
) -> SaturatedRun:
    """``saturated_phase`` through the air model with no retry limit in reach."""
    positions, frames = saturated_phase(n, payload_bytes, frames_per_station)
    unbounded = config.model_copy(update={"retry_limit": UNREACHED_RETRY_LIMIT})
    outcome = decide_phase(unbounded, positions, frames, Key(seed, 0, 0))
    arrival = outcome.arrival_ns[np.arange(len(frames)), frames.receiver]
    start, end = steady_window_ns(arrival, frames.sender)
    counted = (arrival > start) & (arrival <= end)
    attempts = int(outcome.attempts[counted].sum())
    return SaturatedRun(
        throughput_bps(arrival, frames.sender, payload_bytes),
        (attempts - int(counted.sum())) / attempts,
    )


def simulated_throughput_bps(
    config: AirConfig, n: int, payload_bytes: int, frames_per_station: int, seed: int
) -> float:
    """The air model's throughput of ``n`` saturated stations [bit/s] (``saturated_run``)."""
    return saturated_run(config, n, payload_bytes, frames_per_station, seed).throughput_bps


__all__ = [
    "SaturatedRun",
    "backoff_stages",
    "bianchi_ns3_reference_bps",
    "bianchi_tau",
    "bianchi_throughput_bps",
    "saturated_phase",
    "saturated_run",
    "simulated_throughput_bps",
    "steady_window_ns",
    "throughput_bps",
]
