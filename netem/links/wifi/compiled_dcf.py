"""The DCF event loop of ``dcf.py``, compiled: the same events, in the same order, with the
same keyed draws, over arrays instead of objects.

``dcf._Phase`` is the reference this loop is held to (tests/unit/netem/test_wifi_compiled.py):
every station, event and transmission follows it line for line. What differs is storage:
the event heap is an (events, 4) array, the medium's log an (transmissions, 7) array, and a
transmission's overlaps are the log entries whose time on the air meets its own (a frame
that ends at an instant leaves the air before one starts at it, as in the reference), in
log order. Compiled once per install (``cache=True``; docs/model.md §11).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from formation.compiled import jit
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
    DETECT,
    DETECT_SNR,
    DIFS,
    DRAWS,
    EIFS,
    EIFS_NS,
    HEAD_READY,
    IDLE_FROM,
    LOCK,
    NAV,
    NEVER,
    NOISE,
    OVERHEAD,
    PLANNED,
    QEND,
    QPOS,
    RATE,
    RETRY,
    SENDING,
    SENSED_BUSY,
    SIFS,
    SINR,
    SLOT,
    STATION_COLUMNS,
    TRIES,
    TX_DEST,
    TX_END,
    TX_FRAME,
    TX_SENDER,
    TX_SENSED,
    TX_START,
    airtime_ns,
    carrier_busy,
    decoded,
    log_room,
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


# -- the event heap: rows (time, kind, order, value), ordered as tuples --------------------
@jit
def _before(ev: Ints, a: int, b: int) -> bool:
    for c in range(3):
        if ev[a, c] != ev[b, c]:
            return bool(ev[a, c] < ev[b, c])
    return False


@jit
def _swap(ev: Ints, a: int, b: int) -> None:
    for c in range(4):
        ev[a, c], ev[b, c] = ev[b, c], ev[a, c]


@jit
def _push(ev: Ints, size: Ints, time_ns: int, kind: int, value: int) -> Ints:
    if size[0] == ev.shape[0]:
        grown = np.empty((2 * ev.shape[0], 4), dtype=np.int64)
        grown[: ev.shape[0]] = ev
        ev = grown
    size[1] += 1
    i = size[0]
    ev[i, 0], ev[i, 1], ev[i, 2], ev[i, 3] = time_ns, kind, size[1], value
    size[0] += 1
    while i > 0:
        parent = (i - 1) // 2
        if not _before(ev, i, parent):
            break
        _swap(ev, i, parent)
        i = parent
    return ev


@jit
def _pop(ev: Ints, size: Ints) -> None:
    """Drop the heap's first row (read it before)."""
    size[0] -= 1
    last = size[0]
    _swap(ev, 0, last)
    i = 0
    while True:
        left, right, low = 2 * i + 1, 2 * i + 2, i
        if left < last and _before(ev, left, low):
            low = left
        if right < last and _before(ev, right, low):
            low = right
        if low == i:
            return
        _swap(ev, i, low)
        i = low


# -- a station's DCF -----------------------------------------------------------------------
@jit
def _draw(st: Ints, s: int, backoff_state: np.uint64) -> int:
    d = st[s, DRAWS]
    st[s, DRAWS] += 1
    return int(keyed_uniform_after(backoff_state, s, d) * (st[s, CW] + 1))


@jit
def _set_head(st: Ints, s: int, queue: Ints, ready: Ints) -> None:
    st[s, HEAD_READY] = ready[queue[st[s, QPOS]]] if st[s, QPOS] < st[s, QEND] else NEVER


@jit
def _plan(st: Ints, s: int, t: Ints) -> None:
    if st[s, BUSY] or st[s, SENDING] >= 0 or st[s, AWAITING] or st[s, HEAD_READY] >= NEVER:
        st[s, PLANNED] = NEVER
        return
    ifs = t[EIFS_NS] if st[s, EIFS] else t[DIFS]
    backoff_end = st[s, IDLE_FROM] + ifs + st[s, COUNTER] * t[SLOT]
    st[s, PLANNED] = max(st[s, HEAD_READY] + t[DIFS], backoff_end)


@jit
def _sense(
    st: Ints,
    now: int,
    log: Ints,
    on_air: Ints,
    power: Floats,
    levels: Floats,
    t: Ints,
    energy: Floats,
) -> None:
    """Carrier sense at every agent; freeze or resume the backoffs that changed."""
    n = st.shape[0]
    carrier_busy(st, log, on_air, power, levels, energy)
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
@jit
def _next_frame(st: Ints, s: int, queue: Ints, ready: Ints, t: Ints, backoff: np.uint64) -> None:
    """The head frame is done: the next one waits a post-backoff at CWmin."""
    st[s, QPOS] += 1
    _set_head(st, s, queue, ready)
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
    alone: npt.NDArray[np.bool_],
    out: Ints,
    t: Ints,
    backoff: np.uint64,
) -> None:
    """The end of a unicast attempt at its sender."""
    st[s, AWAITING] = 0
    f = queue[st[s, QPOS]]
    d = frames[f, 1]
    m = frames.shape[0]
    if acked or st[s, TRIES] >= t[RETRY]:
        if out[f, d] < 0:
            out[m + f, d] = RETRY_LIMIT if alone[s, d] else BELOW_SENSITIVITY
        _next_frame(st, s, queue, frames[:, 3], t, backoff)
    else:
        st[s, CW] = min(2 * st[s, CW] + 1, t[CW_MAX])
        st[s, COUNTER] = _draw(st, s, backoff)
    _plan(st, s, t)


@jit
def run(
    sender: Ints,
    receiver: Ints,
    payload_bytes: Ints,
    ready_ns: Ints,
    power: Floats,
    levels: Floats,
    t: Ints,
    seed: int,
    epoch: int,
    phase: int,
) -> tuple[Ints, Ints, int]:
    """The phase of the frames ``sender``, ``receiver``, ``payload_bytes`` [B] and
    ``ready_ns`` [ns]; ``power`` (n, n) [mW], what ``j`` receives from ``i``.

    Returns ``out`` (2m, n): each frame's arrival at each agent [ns] in rows ``0 .. m``,
    its cause in rows ``m .. 2m``; ``extra`` (m, 2): each frame's attempts and first start
    [ns]; and when the medium fell silent [ns]."""
    m = sender.shape[0]
    frames = np.empty((m, 4), dtype=np.int64)
    frames[:, 0], frames[:, 1], frames[:, 2], frames[:, 3] = (
        sender,
        receiver,
        payload_bytes,
        ready_ns,
    )
    # a frame the receiver cannot take even on a silent channel
    floor = max(levels[DETECT_SNR], levels[SINR]) * levels[NOISE]
    alone = (power >= levels[DETECT]) & (power >= floor)
    backoff = keyed_state_of(seed, AIR_STREAM, BACKOFF, epoch, phase)
    reception = keyed_state_of(seed, AIR_STREAM, RECEPTION, epoch, phase)
    n = power.shape[0]
    energy = np.zeros(n)  # room for carrier sense's sum
    received = np.zeros(n, dtype=np.int64)  # room for who decoded a frame
    ready = frames[:, 3].copy()
    out = np.full((2 * m, n), -1, dtype=np.int64)
    out[m:] = NOT_ADDRESSED
    extra = np.zeros((m, 2), dtype=np.int64)
    extra[:, 1] = -1
    # the stations' queues: frames by readiness, then index
    order = np.argsort(ready, kind="mergesort")
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
        _set_head(st, s, queue, ready)
    ev = np.empty((m + 8 * n + 16, 4), dtype=np.int64)
    size = np.zeros(2, dtype=np.int64)  # rows in the heap, events pushed
    log = np.zeros((2 * m + 16, 7), dtype=np.int64)
    logged = 0
    on_air = np.zeros(2 * n + 2, dtype=np.int64)  # count, then log indices in log order
    for f in range(m):
        ev = _push(ev, size, ready[f], READY, f)
    now = 0
    while True:
        send_at = NEVER
        for s in range(n):
            send_at = min(send_at, st[s, PLANNED])
        if size[0] > 0 and (ev[0, 0] < send_at or (ev[0, 0] == send_at and ev[0, 1] < SEND)):
            now, kind, value = ev[0, 0], ev[0, 1], ev[0, 3]
            _pop(ev, size)
            first, count = logged, 0
            if kind == END:
                ev = _end(
                    st,
                    value,
                    now,
                    ev,
                    size,
                    log,
                    logged,
                    on_air,
                    queue,
                    frames,
                    power,
                    alone,
                    levels,
                    t,
                    out,
                    backoff,
                    reception,
                    energy,
                    received,
                )
            elif kind == TIMEOUT:
                if st[value, AWAITING] and not st[value, ACK_ON_AIR]:
                    st[value, IDLE_FROM] = max(st[value, IDLE_FROM], now)
                    st[value, EIFS] = 0
                    _resolve(st, value, False, queue, frames, alone, out, t, backoff)
            elif kind == NAV_END:
                _sense(st, now, log, on_air, power, levels, t, energy)
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
                    log = log_room(log, logged + 1)
                    log_transmission(log, logged, acking, ACK, acked, now, t[ACK_NS], t[ACK_RATE])
                    count = 1
            else:  # SENSED
                log[value, TX_SENSED] = 1
                _sense(st, now, log, on_air, power, levels, t, energy)
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
                    log = log_room(log, logged + count + 1)
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
            put_on_air(st, log, first, count, on_air, power, levels, energy)
            for i in range(first, logged):
                ev = _push(ev, size, log[i, TX_START] + t[CCA], SENSED, i)
                ev = _push(ev, size, log[i, TX_END], END, i)
            _sense(st, now, log, on_air, power, levels, t, energy)
    return out, extra, now


@jit
def _end(
    st: Ints,
    index: int,
    now: int,
    ev: Ints,
    size: Ints,
    log: Ints,
    logged: int,
    on_air: Ints,
    queue: Ints,
    frames: Ints,
    power: Floats,
    alone: npt.NDArray[np.bool_],
    levels: Floats,
    t: Ints,
    out: Ints,
    backoff: np.uint64,
    reception: np.uint64,
    energy: Floats,
    received: Ints,
) -> Ints:
    """Log entry ``index`` leaves the air: its receptions, then its sender's next step."""
    n, m = st.shape[0], frames.shape[0]
    s, f, dest = log[index, TX_SENDER], log[index, TX_FRAME], log[index, TX_DEST]
    st[s, SENDING] = -1
    at = 1
    while on_air[at] != index:
        at += 1
    on_air[at : on_air[0]] = on_air[at + 1 : on_air[0] + 1]
    on_air[0] -= 1
    decoded(index, st, log, logged, power, levels, t, reception, received)
    for j in range(n):
        if st[j, LOCK] == index:
            st[j, LOCK] = -1
            st[j, EIFS] = not received[j]
    if f == ACK:
        st[dest, ACK_ON_AIR] = 0
        if st[dest, AWAITING]:
            _resolve(st, dest, received[dest] != 0, queue, frames, alone, out, t, backoff)
    elif dest == BROADCAST:
        for r in range(n):
            if received[r]:
                out[f, r] = now
            if r != s:
                lost = COLLISION if alone[s, r] else BELOW_SENSITIVITY
                out[m + f, r] = DELIVERED if received[r] else lost
        _next_frame(st, s, queue, frames[:, 3], t, backoff)
    else:
        if received[dest]:
            if out[f, dest] < 0:
                out[f, dest] = now
            out[m + f, dest] = DELIVERED
            ev = _push(ev, size, now + t[SIFS], ACK_START, dest * n + s)
            ack_end = now + t[SIFS] + t[ACK_NS]
            overhearing = False
            for r in range(n):
                if received[r] and r != dest:
                    st[r, NAV] = max(st[r, NAV], ack_end)
                    overhearing = True
            if overhearing:
                ev = _push(ev, size, ack_end, NAV_END, 0)
        st[s, AWAITING] = 1
        ev = _push(ev, size, now + t[ACK_TIMEOUT], TIMEOUT, s)
    _sense(st, now, log, on_air, power, levels, t, energy)
    return ev


__all__ = ["DELIVERED", "LATE", "run"]
