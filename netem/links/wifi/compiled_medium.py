"""The shared medium in the compiled event loop (``compiled_dcf``): the arrays it keeps,
what is on the air, who locks onto which frame and who decodes it, as ``medium.py`` and
``reception.py`` decide them.

A station is a row of an int64 array (its DCF state and its lock); a transmission a row of
the log (sender, frame, destination, start, end, rate, sensed); a transmission's overlaps
are the log entries whose time on the air meets its own, in log order (a frame that ends at
an instant leaves the air before one starts at it, as in ``dcf.py``).
"""

from __future__ import annotations

import functools

import numpy as np
import numpy.typing as npt

from formation.compiled import jit
from netem.links.wifi.compiled_reception import frame_success, keyed_uniform_after
from netem.links.wifi.config import AirConfig
from netem.links.wifi.radio import to_mw

Ints = npt.NDArray[np.int64]
Floats = npt.NDArray[np.float64]
ACK = -1  # a transmission's frame when it is an ACK
NEVER = 1 << 62  # [ns] a time that does not come

# a station's columns
HEAD_READY, SENDING, NAV, PLANNED, IDLE_FROM, COUNTER, CW, DRAWS, TRIES, QPOS, QEND = range(11)
BUSY, EIFS, AWAITING, ACK_ON_AIR, LOCK, CARRIER, SENSED_BUSY = range(11, 18)
STATION_COLUMNS = 18
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


@jit
def airtime_ns(t: Ints, frame_bytes: int, rate_kbps: int) -> int:
    if t[OFDM]:
        bits_per_symbol = rate_kbps * 4 // 1000
        symbols = -(-(16 + 8 * frame_bytes + 6) // bits_per_symbol)
        return int(t[PREAMBLE_NS] + 4000 * symbols + t[SYMBOL_EXT])
    return int(t[PREAMBLE_NS] + -(-(8 * frame_bytes * 1000) // rate_kbps) * 1000)


@jit
def carrier_busy(
    st: Ints, log: Ints, on_air: Ints, power: Floats, levels: Floats, energy: Floats
) -> None:
    """Each station's ``CARRIER``: whether its carrier sense finds the medium busy, locked
    onto a sensed frame or the sensed frames' energy above the carrier-sense threshold.
    ``energy`` (n,) is room for the sum."""
    n = st.shape[0]
    energy[:] = 0.0
    sensed = False
    for k in range(on_air[0]):
        i = on_air[k + 1]
        if log[i, TX_SENSED]:
            sensed = True
            for j in range(n):
                energy[j] += power[log[i, TX_SENDER], j]
    for j in range(n):
        lock = st[j, LOCK]
        locked = lock >= 0 and log[lock, TX_SENSED] != 0
        st[j, CARRIER] = sensed and (energy[j] >= levels[ENERGY] or locked)


@jit
def put_on_air(
    st: Ints,
    log: Ints,
    first: int,
    count: int,
    on_air: Ints,
    power: Floats,
    levels: Floats,
    total: Floats,
) -> None:
    """Put log entries ``first .. first + count`` (starting together) on the air and lock
    the free agents that detect one. ``total`` (n,) is room for the power on the air."""
    n = st.shape[0]
    for k in range(count):
        on_air[on_air[0] + 1] = first + k
        on_air[0] += 1
        st[log[first + k, TX_SENDER], LOCK] = -1  # half duplex
    total[:] = 0.0
    for k in range(on_air[0]):
        total += power[log[on_air[k + 1], TX_SENDER]]
    noise, detect, detect_snr = levels[NOISE], levels[DETECT], levels[DETECT_SNR]
    for j in range(n):
        if st[j, LOCK] >= 0 or st[j, SENDING] >= 0:
            continue
        best, best_power = -1, -1.0
        for k in range(count):
            p = power[log[first + k, TX_SENDER], j]
            if p >= detect and p >= detect_snr * (noise + total[j] - p) and p > best_power:
                best, best_power = k, p
        if best >= 0:
            st[j, LOCK] = first + best


@jit
def decoded(
    index: int,
    st: Ints,
    log: Ints,
    size: int,
    power: Floats,
    levels: Floats,
    t: Ints,
    reception_state: np.uint64,
    received: Ints,
) -> None:
    """``received[j]``: whether agent ``j``, locked onto log entry ``index``, decodes it
    (``Reception.decoded``); 0 for the agents not locked onto it."""
    start, end, sender = log[index, TX_START], log[index, TX_END], log[index, TX_SENDER]
    count = 0
    for o in range(size):
        if o != index and log[o, TX_START] < end and log[o, TX_END] > start:
            count += 1
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
    bounds.sort()
    pieces = 0  # distinct bounds, in place
    for k in range(1, bounds.shape[0]):
        if bounds[k] != bounds[pieces]:
            pieces += 1
            bounds[pieces] = bounds[k]
    rate = log[index, TX_RATE]
    ack = log[index, TX_FRAME] == ACK
    noise = levels[NOISE]
    n = st.shape[0]
    who = np.empty(n, dtype=np.int64)  # the agents locked onto the entry
    locked = 0
    for j in range(n):
        received[j] = 0
        if st[j, LOCK] == index:
            who[locked] = j
            locked += 1
    snr = np.empty((locked, pieces))
    for r in range(locked):
        j = who[r]
        signal = power[sender, j]
        worst = 0.0
        for k in range(pieces):
            interference = 0.0
            for q in range(count):
                o = others[q]
                o_start = max(log[o, TX_START], start)
                o_end = min(log[o, TX_END], end)
                if o_start <= bounds[k] < o_end:
                    interference += power[log[o, TX_SENDER], j]
            worst = max(worst, interference)
            snr[r, k] = signal / (noise + interference)
        if not t[CHUNKS]:
            received[j] = signal >= (levels[ACK_SINR] if ack else levels[SINR]) * (noise + worst)
    if not t[CHUNKS] or locked == 0:
        return
    header = (start + t[HEADER_FROM], start + t[HEADER_TO], t[HEADER_RATE])
    payload = (start + t[PREAMBLE_NS], end, rate)
    success = np.empty(locked)
    frame_success(t[OFDM] != 0, header, payload, bounds, pieces, snr, success)
    for r in range(locked):
        # a uniform draw is below 1: a sure frame needs none
        p = success[r]
        received[who[r]] = p >= 1.0 or keyed_uniform_after(reception_state, index, who[r]) < p


@jit
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
def log_room(log: Ints, rows: int) -> Ints:
    if rows <= log.shape[0]:
        return log
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
    levels = np.zeros(6)
    levels[NOISE] = to_mw(config.noise_dbm)
    levels[DETECT] = max(
        float(to_mw(config.preamble_detection_dbm)), float(to_mw(config.rx_sensitivity_dbm))
    )
    levels[DETECT_SNR] = to_mw(config.preamble_detection_snr_db)
    levels[ENERGY] = to_mw(config.carrier_sense_dbm)
    levels[SINR] = to_mw(config.sinr_db)
    levels[ACK_SINR] = to_mw(phy.sinr_threshold_db(phy.control_rate_kbps(config.rate_kbps)))
    return levels
