"""The DCF event loop of ``dcf.py``, compiled: the same events, in the same order, with the
same keyed draws, over arrays instead of objects.

``dcf._Phase`` is the reference this loop is held to (tests/unit/netem/test_wifi_compiled.py):
every station, event and transmission follows it line for line. What differs is storage:
the event heap is an (events, 4) array, the medium's log an (transmissions, 7) array, the
stations an (agents, columns) array and the radio one float array (``compiled_medium``); a
transmission's overlaps are the log entries whose time on the air meets its own (a frame
that ends at an instant leaves the air before one starts at it, as in the reference), in
log order. Compiled once per install (``cache=True``; docs/model.md §11).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from numba.np.unsafe.ndarray import to_fixed_tuple

from formation.compiled import jit, jit_inlined
from netem.links.wifi.compiled_medium import (
    ACK,
    ACK_NS,
    ACK_ON_AIR,
    ACK_RATE,
    ACK_TIMEOUT,
    AWAITING,
    BUSY,
    CARRIER,
    CCA,
    COUNTER,
    CW,
    CW_MAX,
    CW_MIN,
    DIFS,
    DRAWS,
    EIFS,
    EIFS_NS,
    ENERGY,
    HEAD_READY,
    IDLE_FROM,
    LEVEL_FIELDS,
    LOCK,
    NAV,
    NEVER,
    OVERHEAD,
    PLANNED,
    QEND,
    QPOS,
    RATE,
    RECEIVED,
    RETRY,
    SENDING,
    SENSED_BUSY,
    SIFS,
    SLOT,
    STATION_COLUMNS,
    TIMING_FIELDS,
    TRIES,
    TX_DEST,
    TX_END,
    TX_FRAME,
    TX_SENDER,
    TX_SENSED,
    TX_START,
    Levels,
    Timing,
    airtime_ns,
    alone_floor,
    decoded,
    log_grown,
    log_transmission,
    put_on_air,
)
from netem.links.wifi.compiled_reception import keyed_state_of, keyed_uniform_after
from netem.links.wifi.radio import AIR_STREAM
from netem.links.wifi.reception import RECEPTION

Ints = npt.NDArray[np.int64]
Floats = npt.NDArray[np.float64]
BACKOFF = 0  # sub-stream of AIR_STREAM
LONG_AGO = -(1 << 40)  # [ns] the medium was idle since before the phase
BROADCAST = -1
END, TIMEOUT, NAV_END, READY, ACK_START, SEND, SENSED = range(7)
DELIVERED, COLLISION, BELOW_SENSITIVITY, RETRY_LIMIT, LATE, NOT_ADDRESSED = range(6)
PUSHES = 3  # the most events one event pushes, besides two per transmission it starts


# -- the event heap: rows (time, kind, order, value) from row 1, ordered as tuples; row 0
# holds the rows in use and the events pushed so far -------------------------------------
@jit
def _earlier(a0: int, a1: int, a2: int, b0: int, b1: int, b2: int) -> bool:
    if a0 != b0:
        return a0 < b0
    if a1 != b1:
        return a1 < b1
    return a2 < b2


@jit_inlined
def _push(ev: Ints, time_ns: int, kind: int, value: int) -> None:
    """Push an event; the caller made room (``_heap_grown``)."""
    ev[0, 0] += 1
    ev[0, 1] += 1
    i = ev[0, 0]
    ev[i, 0], ev[i, 1], ev[i, 2], ev[i, 3] = time_ns, kind, ev[0, 1], value
    while i > 1:
        up = i // 2
        if not _earlier(ev[i, 0], ev[i, 1], ev[i, 2], ev[up, 0], ev[up, 1], ev[up, 2]):
            break
        for c in range(4):  # a call taking ``ev`` would cost reference counts
            ev[i, c], ev[up, c] = ev[up, c], ev[i, c]
        i = up


@jit_inlined
def _pop(ev: Ints) -> None:
    """Drop the heap's first row (read it before)."""
    last = ev[0, 0]
    ev[0, 0] -= 1
    for c in range(4):
        ev[1, c] = ev[last, c]
    last -= 1
    i = 1
    while True:
        low = i
        for child in (2 * i, 2 * i + 1):
            if child <= last and _earlier(
                ev[child, 0], ev[child, 1], ev[child, 2], ev[low, 0], ev[low, 1], ev[low, 2]
            ):
                low = child
        if low == i:
            return
        for c in range(4):
            ev[i, c], ev[low, c] = ev[low, c], ev[i, c]
        i = low


@jit
def _heap_grown(ev: Ints, more: int) -> Ints:
    grown = np.empty((2 * ev.shape[0] + more, 4), dtype=np.int64)
    grown[: ev.shape[0]] = ev
    return grown


# -- a station's DCF -----------------------------------------------------------------------
@jit_inlined
def _draw(st: Ints, s: int, backoff_state: np.uint64) -> int:
    d = st[s, DRAWS]
    st[s, DRAWS] += 1
    return int(keyed_uniform_after(backoff_state, s, d) * (st[s, CW] + 1))


@jit_inlined
def _set_head(st: Ints, s: int, queue: Ints, frames: Ints) -> None:
    st[s, HEAD_READY] = frames[queue[st[s, QPOS]], 3] if st[s, QPOS] < st[s, QEND] else NEVER


@jit_inlined
def _plan(st: Ints, s: int, t: Timing) -> None:
    if st[s, BUSY] or st[s, SENDING] >= 0 or st[s, AWAITING] or st[s, HEAD_READY] >= NEVER:
        st[s, PLANNED] = NEVER
        return
    ifs = t[EIFS_NS] if st[s, EIFS] else t[DIFS]
    backoff_end = st[s, IDLE_FROM] + ifs + st[s, COUNTER] * t[SLOT]
    st[s, PLANNED] = max(st[s, HEAD_READY] + t[DIFS], backoff_end)


@jit_inlined
def _sense(
    st: Ints, now: int, log: Ints, on_air: Ints, air: Floats, t: Timing, busy_mw: float
) -> None:
    """Carrier sense at every agent (locked onto a sensed frame, or the sensed frames' energy
    at least ``busy_mw``); freeze or resume the backoffs that changed."""
    n = st.shape[0]
    for j in range(n):
        air[n, j] = 0.0  # the sensed energy at each agent
    sensed = False
    for k in range(on_air[0]):
        i = on_air[k + 1]
        if log[i, TX_SENSED]:
            sensed = True
            sender = log[i, TX_SENDER]
            for j in range(n):
                air[n, j] += air[sender, j]
    for j in range(n):
        lock = st[j, LOCK]
        locked = lock >= 0 and log[lock, TX_SENSED] != 0
        st[j, CARRIER] = sensed and (air[n, j] >= busy_mw or locked)
    same = True
    for s in range(n):
        busy = st[s, SENDING] >= 0 or st[s, CARRIER] != 0 or st[s, NAV] > now
        st[s, SENSED_BUSY] = busy
        same = same and busy == (st[s, BUSY] != 0)
    if same:
        return
    # freeze: keep the slots not counted yet; a frame that was waiting out its DIFS on an
    # idle medium draws no backoff (ns-3)
    for s in range(n):
        if st[s, SENSED_BUSY] and not st[s, BUSY]:
            start = st[s, IDLE_FROM] + (t[EIFS_NS] if st[s, EIFS] else t[DIFS])
            done = (now - start) // t[SLOT] if now > start else 0
            st[s, COUNTER] = max(st[s, COUNTER] - done, 0)
            st[s, PLANNED] = NEVER
    for s in range(n):  # the medium turned idle: ``_plan`` of each, written out (no call)
        if not st[s, SENSED_BUSY] and st[s, BUSY]:
            st[s, IDLE_FROM] = now
            st[s, PLANNED] = NEVER
            if not st[s, AWAITING] and st[s, HEAD_READY] < NEVER:  # and not sending: idle
                ifs = t[EIFS_NS] if st[s, EIFS] else t[DIFS]
                backoff_end = now + ifs + st[s, COUNTER] * t[SLOT]
                st[s, PLANNED] = max(st[s, HEAD_READY] + t[DIFS], backoff_end)
        st[s, BUSY] = st[s, SENSED_BUSY]


# -- the stations' events ------------------------------------------------------------------
@jit_inlined
def _next_frame(st: Ints, s: int, queue: Ints, frames: Ints, t: Timing, backoff: np.uint64) -> None:
    """The head frame is done: the next one waits a post-backoff at CWmin."""
    st[s, QPOS] += 1
    _set_head(st, s, queue, frames)
    st[s, TRIES] = 0
    st[s, CW] = t[CW_MIN]
    st[s, COUNTER] = _draw(st, s, backoff)


@jit
def _resolve(
    st: Ints,
    s: int,
    acked: bool,
    queue: Ints,
    frames: Ints,
    air: Floats,
    levels: Levels,
    out: Ints,
    t: Timing,
    backoff: np.uint64,
) -> None:
    """The end of a unicast attempt at its sender."""
    st[s, AWAITING] = 0
    f = queue[st[s, QPOS]]
    d = frames[f, 1]
    m = frames.shape[0]
    if acked or st[s, TRIES] >= t[RETRY]:
        if out[f, d] < 0:
            alone = air[s, d] >= alone_floor(levels)
            out[m + f, d] = RETRY_LIMIT if alone else BELOW_SENSITIVITY
        _next_frame(st, s, queue, frames, t, backoff)
    else:
        st[s, CW] = min(2 * st[s, CW] + 1, t[CW_MAX])
        st[s, COUNTER] = _draw(st, s, backoff)
    _plan(st, s, t)


@jit
def run(
    frames: Ints,
    air: Floats,
    level_mw: Floats,
    timing: Ints,
    seed: int,
    epoch: int,
    phase: int,
) -> tuple[Ints, Ints, int]:
    """The phase of ``frames`` (m, 4): each frame's sender, receiver, payload [B] and
    readiness [ns]; ``air`` (n + 2, n): rows ``0 .. n`` what ``j`` receives from ``i`` [mW],
    then room (``compiled_medium``).

    Returns ``out`` (2m, n): each frame's arrival at each agent [ns] in rows ``0 .. m``,
    its cause in rows ``m .. 2m``; ``extra`` (m, 2): each frame's attempts and first start
    [ns]; and when the medium fell silent [ns]."""
    m, n = frames.shape[0], air.shape[1]
    # numba's intrinsic takes the typing context first: mypy sees one argument too few
    levels: Levels = to_fixed_tuple(level_mw, LEVEL_FIELDS)  # type: ignore[call-arg]
    t: Timing = to_fixed_tuple(timing, TIMING_FIELDS)
    backoff = keyed_state_of(seed, AIR_STREAM, BACKOFF, epoch, phase)
    reception = keyed_state_of(seed, AIR_STREAM, RECEPTION, epoch, phase)
    out = np.full((2 * m, n), -1, dtype=np.int64)
    out[m:] = NOT_ADDRESSED
    extra = np.zeros((m, 2), dtype=np.int64)
    extra[:, 1] = -1
    # the stations' queues: frames by readiness, then index
    order = np.argsort(frames[:, 3], kind="mergesort")
    queue = np.empty(m, dtype=np.int64)
    st = np.zeros((n, STATION_COLUMNS), dtype=np.int64)
    for f in range(m):
        st[frames[f, 0], QEND] += 1
    at = 0
    for s in range(n):
        st[s, QPOS] = at
        at += st[s, QEND]
        st[s, QEND] = st[s, QPOS]
    for f in order:
        s = frames[f, 0]
        queue[st[s, QEND]] = f
        st[s, QEND] += 1
    st[:, SENDING] = -1
    st[:, PLANNED] = NEVER
    st[:, IDLE_FROM] = LONG_AGO
    st[:, CW] = t[CW_MIN]
    st[:, LOCK] = -1
    for s in range(n):
        _set_head(st, s, queue, frames)
    ev = np.zeros((m + 8 * n + 16, 4), dtype=np.int64)
    log = np.zeros((2 * m + 16, 7), dtype=np.int64)
    logged = 0
    on_air = np.zeros(2 * n + 2, dtype=np.int64)  # count, then log indices in log order
    for f in range(m):
        _push(ev, frames[f, 3], READY, f)
    now = 0
    while True:
        if ev[0, 0] + 2 * n + PUSHES >= ev.shape[0]:
            ev = _heap_grown(ev, 2 * n + PUSHES)
        send_at = NEVER
        for s in range(n):
            send_at = min(send_at, st[s, PLANNED])
        soonest = ev[1, 0] if ev[0, 0] > 0 else NEVER
        if ev[0, 0] > 0 and (soonest < send_at or (soonest == send_at and ev[1, 1] < SEND)):
            now, kind, value = soonest, ev[1, 1], ev[1, 3]
            _pop(ev)
            first, count = logged, 0
            if kind == END:
                _end(
                    st,
                    value,
                    now,
                    ev,
                    log,
                    logged,
                    on_air,
                    queue,
                    frames,
                    air,
                    levels,
                    t,
                    out,
                    backoff,
                    reception,
                )
            elif kind == TIMEOUT:
                if st[value, AWAITING] and not st[value, ACK_ON_AIR]:
                    st[value, IDLE_FROM] = max(st[value, IDLE_FROM], now)
                    st[value, EIFS] = 0
                    _resolve(st, value, False, queue, frames, air, levels, out, t, backoff)
            elif kind == NAV_END:
                _sense(st, now, log, on_air, air, t, levels[ENERGY])
            elif kind == READY:
                s = frames[value, 0]
                head = queue[st[s, QPOS]] if st[s, QPOS] < st[s, QEND] else -1
                contending = head >= 0 and st[s, SENDING] < 0 and not st[s, AWAITING]
                if head == value and contending and st[s, BUSY] and st[s, COUNTER] == 0:
                    st[s, COUNTER] = _draw(st, s, backoff)
                _plan(st, s, t)
            elif kind == ACK_START:
                acking, acked = value // n, value % n  # the data's receiver and sender
                if st[acking, SENDING] < 0:
                    st[acked, ACK_ON_AIR] = 1
                    if logged + 1 > log.shape[0]:
                        log = log_grown(log)
                    log_transmission(log, logged, acking, ACK, acked, now, t[ACK_NS], t[ACK_RATE])
                    count = 1
            else:  # SENSED
                log[value, TX_SENSED] = 1
                _sense(st, now, log, on_air, air, t, levels[ENERGY])
        elif send_at < NEVER:
            now = send_at
            first, count = logged, 0
            for s in range(n):
                if st[s, PLANNED] == send_at:
                    f = queue[st[s, QPOS]]
                    extra[f, 0] += 1
                    st[s, TRIES] += 1
                    if extra[f, 1] < 0:
                        extra[f, 1] = now
                    airtime = airtime_ns(t, frames[f, 2] + t[OVERHEAD], t[RATE])
                    if logged + count + 1 > log.shape[0]:
                        log = log_grown(log)
                    log_transmission(log, logged + count, s, f, frames[f, 1], now, airtime, t[RATE])
                    count += 1
        else:
            break
        if count:  # transmit: the new log entries take the air
            logged += count
            for i in range(first, logged):
                st[log[i, TX_SENDER], SENDING] = i
                st[log[i, TX_SENDER], PLANNED] = NEVER
                st[log[i, TX_SENDER], EIFS] = 0  # a transmission ends the EIFS
            put_on_air(st, log, first, count, on_air, air, levels)
            for i in range(first, logged):
                _push(ev, log[i, TX_START] + t[CCA], SENSED, i)
                _push(ev, log[i, TX_END], END, i)
            _sense(st, now, log, on_air, air, t, levels[ENERGY])
    return out, extra, now


@jit
def _end(
    st: Ints,
    index: int,
    now: int,
    ev: Ints,
    log: Ints,
    logged: int,
    on_air: Ints,
    queue: Ints,
    frames: Ints,
    air: Floats,
    levels: Levels,
    t: Timing,
    out: Ints,
    backoff: np.uint64,
    reception: np.uint64,
) -> None:
    """Log entry ``index`` leaves the air: its receptions, then its sender's next step."""
    n, m = st.shape[0], frames.shape[0]
    s, f, dest = log[index, TX_SENDER], log[index, TX_FRAME], log[index, TX_DEST]
    st[s, SENDING] = -1
    at = 1
    while on_air[at] != index:
        at += 1
    for k in range(at, on_air[0]):
        on_air[k] = on_air[k + 1]
    on_air[0] -= 1
    decoded(index, st, log, logged, air, levels, t, reception)
    for j in range(n):
        if st[j, LOCK] == index:
            st[j, LOCK] = -1
            st[j, EIFS] = not st[j, RECEIVED]
    if f == ACK:
        st[dest, ACK_ON_AIR] = 0
        if st[dest, AWAITING]:
            acked = st[dest, RECEIVED] != 0
            _resolve(st, dest, acked, queue, frames, air, levels, out, t, backoff)
    elif dest == BROADCAST:
        floor = alone_floor(levels)
        for r in range(n):
            if st[r, RECEIVED]:
                out[f, r] = now
            if r != s:
                lost = COLLISION if air[s, r] >= floor else BELOW_SENSITIVITY
                out[m + f, r] = DELIVERED if st[r, RECEIVED] else lost
        _next_frame(st, s, queue, frames, t, backoff)
    else:
        if st[dest, RECEIVED]:
            if out[f, dest] < 0:
                out[f, dest] = now
            out[m + f, dest] = DELIVERED
            _push(ev, now + t[SIFS], ACK_START, dest * n + s)
            ack_end = now + t[SIFS] + t[ACK_NS]
            overhearing = False
            for r in range(n):
                if st[r, RECEIVED] and r != dest:
                    st[r, NAV] = max(st[r, NAV], ack_end)
                    overhearing = True
            if overhearing:
                _push(ev, ack_end, NAV_END, 0)
        st[s, AWAITING] = 1
        _push(ev, now + t[ACK_TIMEOUT], TIMEOUT, s)
    _sense(st, now, log, on_air, air, t, levels[ENERGY])


__all__ = ["DELIVERED", "LATE", "run"]
