"""The shared medium in the compiled event loop (``compiled_dcf``): the arrays it keeps,
what is on the air, who locks onto which frame and who decodes it, as ``medium.py`` and
``reception.py`` decide them.

A station is a row of an int64 array (its DCF state, its lock and whether it decoded the
frame that just ended); a transmission a row of the log (sender, frame, destination, start,
end, rate, sensed); a transmission's overlaps are the log entries whose time on the air meets
its own, in log order (a frame that ends at an instant leaves the air before one starts at
it, as in ``dcf.py``). The radio is one float array ``air`` (n + 2, n): row ``i < n`` what
each agent receives from ``i`` [mW], then two rows of room, the energy each agent's carrier
sense adds up and the power on the air at each. The loop's functions take these few arrays
so that a call costs few reference counts.
"""

from __future__ import annotations

import functools

import numpy as np
import numpy.typing as npt

from formation.compiled import jit, jit_inlined
from netem.links.wifi.compiled_reception import (
    frame_success,
    frame_success_alone,
    keyed_uniform_after,
)
from netem.links.wifi.config import AirConfig
from netem.links.wifi.radio import to_mw

Ints = npt.NDArray[np.int64]
Floats = npt.NDArray[np.float64]
# the phase's timing and the radio's levels as tuples: passed by value, without the
# reference counts an array argument costs each call
Timing = tuple[int, ...]
Levels = tuple[float, ...]
ACK = -1  # a transmission's frame when it is an ACK
NEVER = 1 << 62  # [ns] a time that does not come

# a station's columns
HEAD_READY, SENDING, NAV, PLANNED, IDLE_FROM, COUNTER, CW, DRAWS, TRIES, QPOS, QEND = range(11)
BUSY, EIFS, AWAITING, ACK_ON_AIR, LOCK, CARRIER, SENSED_BUSY, RECEIVED = range(11, 19)
STATION_COLUMNS = 19
# a transmission's columns
TX_SENDER, TX_FRAME, TX_DEST, TX_START, TX_END, TX_RATE, TX_SENSED = range(7)
# the scalars: phase timing and sizes
(SLOT, SIFS, DIFS, EIFS_NS, ACK_NS, ACK_TIMEOUT, CCA, RATE, ACK_RATE, RETRY, CW_MIN, CW_MAX) = (
    range(12)
)
HEADER_FROM, HEADER_TO, HEADER_RATE, OVERHEAD, PREAMBLE_NS, SYMBOL_EXT, OFDM, CHUNKS = range(12, 20)
TIMING_FIELDS = 20
# the radio's levels [mW]
NOISE, DETECT, DETECT_SNR, ENERGY, SINR, ACK_SINR = range(6)
LEVEL_FIELDS = 6


@jit
def airtime_ns(t: Timing, frame_bytes: int, rate_kbps: int) -> int:
    if t[OFDM]:
        bits_per_symbol = rate_kbps * 4 // 1000
        symbols = -(-(16 + 8 * frame_bytes + 6) // bits_per_symbol)
        return int(t[PREAMBLE_NS] + 4000 * symbols + t[SYMBOL_EXT])
    return int(t[PREAMBLE_NS] + -(-(8 * frame_bytes * 1000) // rate_kbps) * 1000)


@jit
def alone_floor(levels: Levels) -> float:
    """The least power [mW] at which a receiver would take a frame on a silent channel."""
    return max(levels[DETECT], max(levels[DETECT_SNR], levels[SINR]) * levels[NOISE])


@jit_inlined
def put_on_air(
    st: Ints, log: Ints, first: int, count: int, on_air: Ints, air: Floats, levels: Levels
) -> None:
    """Put log entries ``first .. first + count`` (starting together) on the air and lock
    the free agents that detect one."""
    n = air.shape[1]
    for k in range(count):
        on_air[on_air[0] + 1] = first + k
        on_air[0] += 1
        st[log[first + k, TX_SENDER], LOCK] = -1  # half duplex
    total = n + 1
    for j in range(n):
        air[total, j] = 0.0
    for k in range(on_air[0]):
        sender = log[on_air[k + 1], TX_SENDER]
        for j in range(n):
            air[total, j] += air[sender, j]
    noise, detect, detect_snr = levels[NOISE], levels[DETECT], levels[DETECT_SNR]
    for j in range(n):
        if st[j, LOCK] >= 0 or st[j, SENDING] >= 0:
            continue
        best, best_power = -1, -1.0
        for k in range(count):
            p = air[log[first + k, TX_SENDER], j]
            if p >= detect and p >= detect_snr * (noise + air[total, j] - p) and p > best_power:
                best, best_power = k, p
        if best >= 0:
            st[j, LOCK] = first + best


@jit
def decoded(
    index: int,
    st: Ints,
    log: Ints,
    size: int,
    air: Floats,
    levels: Levels,
    t: Timing,
    reception_state: np.uint64,
) -> None:
    """``st[j, RECEIVED]``: whether agent ``j``, locked onto log entry ``index``, decodes it
    (``Reception.decoded``); 0 for the agents not locked onto it."""
    start, end, sender = log[index, TX_START], log[index, TX_END], log[index, TX_SENDER]
    count = 0
    for o in range(size):
        if o != index and log[o, TX_START] < end and log[o, TX_END] > start:
            count += 1
    if count == 0:
        _decoded_alone(index, st, log, air, levels, t, reception_state)
        return
    # the overlapping entries, then the times the interference changes
    work = np.empty(3 * count + 2, dtype=np.int64)
    others, bounds = work[:count], work[count:]
    count = 0
    for o in range(size):
        if o != index and log[o, TX_START] < end and log[o, TX_END] > start:
            others[count] = o
            count += 1
    bounds[0], bounds[1] = start, end
    for k in range(count):
        bounds[2 + 2 * k] = max(log[others[k], TX_START], start)
        bounds[3 + 2 * k] = min(log[others[k], TX_END], end)
    for k in range(1, bounds.shape[0]):  # a few: insertion sort
        v, i = bounds[k], k - 1
        while i >= 0 and bounds[i] > v:
            bounds[i + 1] = bounds[i]
            i -= 1
        bounds[i + 1] = v
    pieces = 0  # distinct bounds, in place
    for k in range(1, bounds.shape[0]):
        if bounds[k] != bounds[pieces]:
            pieces += 1
            bounds[pieces] = bounds[k]
    rate = log[index, TX_RATE]
    ack = log[index, TX_FRAME] == ACK
    noise = levels[NOISE]
    n = air.shape[1]
    locked = 0
    for j in range(n):
        st[j, RECEIVED] = 0
        locked += st[j, LOCK] == index
    snr = np.empty((locked, pieces))
    r = 0
    for j in range(n):
        if st[j, LOCK] != index:
            continue
        signal = air[sender, j]
        worst = 0.0
        for k in range(pieces):
            interference = 0.0
            for q in range(count):
                o = others[q]
                o_start = max(log[o, TX_START], start)
                o_end = min(log[o, TX_END], end)
                if o_start <= bounds[k] < o_end:
                    interference += air[log[o, TX_SENDER], j]
            worst = max(worst, interference)
            snr[r, k] = signal / (noise + interference)
        r += 1
        if not t[CHUNKS]:
            threshold = levels[ACK_SINR] if ack else levels[SINR]
            st[j, RECEIVED] = signal >= threshold * (noise + worst)
    if not t[CHUNKS] or locked == 0:
        return
    header = (start + t[HEADER_FROM], start + t[HEADER_TO], t[HEADER_RATE])
    payload = (start + t[PREAMBLE_NS], end, rate)
    success = np.empty(locked)
    frame_success(t[OFDM] != 0, header, payload, bounds, pieces, snr, success)
    r = 0
    for j in range(n):
        if st[j, LOCK] == index:
            # a uniform draw is below 1: a sure frame needs none
            p = success[r]
            st[j, RECEIVED] = p >= 1.0 or keyed_uniform_after(reception_state, index, j) < p
            r += 1


@jit_inlined
def _decoded_alone(
    index: int,
    st: Ints,
    log: Ints,
    air: Floats,
    levels: Levels,
    t: Timing,
    reception_state: np.uint64,
) -> None:
    """``decoded`` for a transmission nothing overlaps: one piece, without arrays."""
    start, end, sender = log[index, TX_START], log[index, TX_END], log[index, TX_SENDER]
    noise = levels[NOISE]
    threshold = levels[ACK_SINR] if log[index, TX_FRAME] == ACK else levels[SINR]
    header = (start + t[HEADER_FROM], start + t[HEADER_TO], t[HEADER_RATE])
    payload = (start + t[PREAMBLE_NS], end, log[index, TX_RATE])
    for j in range(air.shape[1]):
        st[j, RECEIVED] = 0
        if st[j, LOCK] != index:
            continue
        signal = air[sender, j]
        if not t[CHUNKS]:
            st[j, RECEIVED] = signal >= threshold * noise
            continue
        p = frame_success_alone(t[OFDM] != 0, header, payload, start, end, signal / noise)
        st[j, RECEIVED] = p >= 1.0 or keyed_uniform_after(reception_state, index, j) < p


@jit_inlined
def log_transmission(
    log: Ints, i: int, sender: int, frame: int, dest: int, now: int, airtime: int, rate: int
) -> None:
    log[i, TX_SENDER], log[i, TX_FRAME], log[i, TX_DEST] = sender, frame, dest
    log[i, TX_START], log[i, TX_END], log[i, TX_RATE], log[i, TX_SENSED] = (
        now,
        now + airtime,
        rate,
        0,
    )


@jit
def log_grown(log: Ints) -> Ints:
    grown = np.zeros((2 * log.shape[0], 7), dtype=np.int64)
    grown[: log.shape[0]] = log
    return grown


@functools.lru_cache(maxsize=64)
def timing(config: AirConfig) -> Ints:
    phy, rate = config.physical, config.rate_kbps
    ack_rate = phy.control_rate_kbps(rate)
    header_from, header_to = phy.header_window_ns
    t = np.zeros(TIMING_FIELDS, dtype=np.int64)
    t[[SLOT, SIFS, DIFS, EIFS_NS, ACK_NS, ACK_TIMEOUT, CCA, RATE, ACK_RATE]] = (
        phy.slot_ns,
        phy.sifs_ns,
        phy.difs_ns,
        phy.eifs_ns(),
        phy.ack_ns(rate),
        phy.ack_timeout_ns(),
        phy.cca_ns,
        rate,
        ack_rate,
    )
    t[[RETRY, CW_MIN, CW_MAX, HEADER_FROM, HEADER_TO, HEADER_RATE]] = (
        config.retry_limit,
        *config.window,
        header_from,
        header_to,
        phy.header_kbps,
    )
    t[[OVERHEAD, PREAMBLE_NS, SYMBOL_EXT, OFDM, CHUNKS]] = (
        config.mac_overhead_bytes,
        phy.preamble_ns,
        phy.signal_extension_ns,
        phy.ofdm,
        config.error_model == "chunks",
    )
    return t


@functools.lru_cache(maxsize=64)
def levels_of(config: AirConfig) -> Floats:
    phy = config.physical
    levels = np.zeros(LEVEL_FIELDS)
    levels[NOISE] = to_mw(config.noise_dbm)
    levels[DETECT] = max(
        float(to_mw(config.preamble_detection_dbm)), float(to_mw(config.rx_sensitivity_dbm))
    )
    levels[DETECT_SNR] = to_mw(config.preamble_detection_snr_db)
    levels[ENERGY] = to_mw(config.carrier_sense_dbm)
    levels[SINR] = to_mw(config.sinr_db)
    levels[ACK_SINR] = to_mw(phy.sinr_threshold_db(phy.control_rate_kbps(config.rate_kbps)))
    return levels
