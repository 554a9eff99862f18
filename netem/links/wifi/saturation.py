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
only to its sender (if it draws 0), and the colliders wait ACKTimeout before they count again
(I. Tinnirello, G. Bianchi, Y. Xiao, "Refinements on IEEE 802.11 distributed coordination
function modeling approaches", IEEE Trans. Veh. Technol. 59(3), 2010).
:func:`refined_throughput_bps` writes these rules into Bianchi's chain (docs/model.md §11):
every busy period is followed by one slot ``σ`` no waiting station sends in; with ``q = 1 / W``
the sender of a success sends again in it (a success no one contends), and otherwise waits
``U{1 .. W − 1} − 1`` slots; a collider waits ``d = ACKTimeout / σ − 1`` slots more than its
window, so

    τ = Σ p^i / Σ p^i (1 + B_i),  B_0 = (W − 2) / 2,  B_i = (W_i − 1) / 2 + d,
    S = P_s P_tr L / (1 − q) / ((1 − P_tr) σ + P_tr P_s (T_s / (1 − q) + σ) + P_tr (1 − P_s)(T_c + σ))

with ``W_i = 2^min(i, m) W``; without the rules (``q = 0``, ``d = 0``, ``B_0 = (W − 1) / 2``,
no added ``σ``) these are eqs. 7 and 13.
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
    p_tr = 1.0 - (1.0 - tau) ** n
    p_s = n * tau * (1.0 - tau) ** (n - 1) / p_tr
    slot_mean_ns = (1 - p_tr) * slot + p_tr * p_s * t_s + p_tr * (1 - p_s) * t_c
    return p_s * p_tr * 8 * payload_bytes / slot_mean_ns * 1e9


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


def collider_wait_slots(config: AirConfig) -> float:
    """``d``: the slots a collider counts no backoff for beyond the others, ACKTimeout less
    the first slot after the busy period, which no one else uses either."""
    phy = config.physical
    return phy.ack_timeout_ns() / phy.slot_ns - 1


def refined_tau(n: int, w: int, m: int, collider_wait_slots: float) -> tuple[float, float]:
    """``(τ, p)`` of Bianchi's chain under the standard's access after a busy period (module
    docstring): ``p`` counts the attempts that contend, not the first slot's free ones."""

    def gap(tau: float) -> float:
        p = 1.0 - (1.0 - tau) ** (n - 1)
        # Σ p^i W_i, W_i = 2^min(i, m) W
        windows = w * (sum((2.0 * p) ** i for i in range(m)) + (2.0 * p) ** m / (1 - p))
        # Σ p^i (1 + B_i): the stage's mean backoff and its transmission slot
        slots = (1 / (1 - p) + windows) / 2 - 0.5 + collider_wait_slots * p / (1 - p)
        return tau - 1.0 / (1 - p) / slots

    # above 1/2 no window can be: and (1 − τ)^(n − 1) would round to 0
    tau = float(brentq(gap, 1e-12, 0.5, xtol=1e-15))
    return tau, 1.0 - (1.0 - tau) ** (n - 1)


def refined_p_per_attempt(n: int, w: int, m: int, collider_wait_slots: float) -> float:
    """The refined chain's collided attempts over all attempts, the free ones counted: one in
    ``W − 1`` successes is followed by a free attempt, and so on."""
    p = refined_tau(n, w, m, collider_wait_slots)[1]
    contended = 1 / (1 - p)  # attempts a frame, and per frame that many
    free = 1 / (w - 1)  # free attempts per contended success: q / (1 − q), q = 1 / W
    return (contended - 1) / (contended + free)


def refined_throughput_bps(config: AirConfig, n: int, payload_bytes: int) -> float:
    """The saturation throughput of ``n`` stations [bit/s] by Bianchi's chain with the
    standard's access after a busy period (module docstring)."""
    w, m = backoff_stages(config)
    slot, t_s, t_c = _slot_times_ns(config, payload_bytes)
    tau, _ = refined_tau(n, w, m, collider_wait_slots(config))
    free = 1.0 / w
    p_tr = 1.0 - (1.0 - tau) ** n
    p_s = n * tau * (1.0 - tau) ** (n - 1) / p_tr
    success = t_s / (1 - free) + slot
    slot_mean_ns = (1 - p_tr) * slot + p_tr * p_s * success + p_tr * (1 - p_s) * (t_c + slot)
    return p_s * p_tr * 8 * payload_bytes / (1 - free) / slot_mean_ns * 1e9


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
    "bianchi_tau",
    "bianchi_throughput_bps",
    "collider_wait_slots",
    "refined_p_per_attempt",
    "refined_tau",
    "refined_throughput_bps",
    "saturated_phase",
    "saturated_run",
    "simulated_throughput_bps",
    "steady_window_ns",
    "throughput_bps",
]
