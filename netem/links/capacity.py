"""A link's capacity: a rate-limited FIFO queue simulated in virtual time (docs/model.md §9).

One queue serves the packets of its scope (a directed link, a sender's radio or a named
medium) in arrival order at ``rate_bps``, as Linux does:

- ``burst_bytes == 0`` is ``tc netem rate``: a packet is on the wire for ``size / rate``
  and leaves when its last bit is sent, ``d_k = max(a_k, d_{k-1}) + 8 s_k / r``; so the
  k-th packet (1-based) of a burst of equal packets arriving at 0 leaves at ``k L / r``.
- ``burst_bytes > 0`` is ``tc tbf``: a bucket of ``burst_bytes`` tokens, full at the start,
  fills at ``r / 8`` bytes a second; the head packet leaves at once when the bucket holds
  its size and takes that many tokens, ``d_k = max(a_k, d_{k-1}, t0 + (s_k − T0) 8 / r)``.
  A packet larger than the bucket never gets its tokens: tbf drops it (``oversize``).

A packet's size is its payload's bytes plus ``overhead_bytes``. It waits in the queue from
its arrival to its departure; ``limit_packets`` / ``limit_bytes`` bound the waiting packets
(the arriving one included, as Linux's ``pfifo`` / ``bfifo`` count). A packet that finds the
queue full is dropped (``tail``) or pushes out the oldest waiting packet that is not on the
wire (``oldest``, a ROS keep-last queue); either drop is ``queue_full``. A packet that leaves
after its ``deadline`` (its phase's, in a run) is ``queue_late``: it still took its share of
the link, which does not know deadlines.

Pure: arrays in, arrays out, no clock; the state between calls is a :class:`QueueState`.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Literal, NamedTuple

import numpy as np
import numpy.typing as npt

Floats = npt.NDArray[np.float64]
Ints = npt.NDArray[np.int64]
Codes = npt.NDArray[np.int8]

Policy = Literal["tail", "oldest"]
# a packet's fate, as codes (arrays) and names (records); 0 is "the queue passed it in time"
REASONS: tuple[str, ...] = ("", "queue_full", "queue_late", "oversize")
PASSED, QUEUE_FULL, QUEUE_LATE, OVERSIZE = range(len(REASONS))


@dataclass(frozen=True)
class QueueParams:
    """A queue's parameters, as ``tc`` names them; ``None`` limits are unbounded."""

    rate_bps: float  # [bit/s]
    burst_bytes: int = 0  # [B] 0: netem rate (serialisation), > 0: tbf's bucket
    limit_packets: int | None = None
    limit_bytes: int | None = None  # [B], sizes with their overhead
    overhead_bytes: int = 0  # [B] added to each payload
    policy: Policy = "tail"

    def __post_init__(self) -> None:
        # the scenario validates with the file's names; this guards direct use of the core
        if not self.rate_bps > 0.0:
            raise ValueError(f"rate_bps = {self.rate_bps!r}; expected > 0")
        for name in ("limit_packets", "limit_bytes"):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise ValueError(f"{name} = {value!r}; expected >= 1 or None")
        if self.burst_bytes < 0 or self.overhead_bytes < 0:
            raise ValueError("burst_bytes and overhead_bytes must be >= 0")


@dataclass(frozen=True)
class QueueState:
    """What a queue carries from one call to the next.

    ``clock_s``: the last departure [s]; ``tokens_bytes``: the bucket then [B] (tbf);
    ``backlog_s`` / ``backlog_bytes``: departure times [s] and sizes [B] of packets of
    earlier calls still waiting (they are committed: a later call cannot push them out).
    """

    clock_s: float = -np.inf
    tokens_bytes: float = np.inf  # a full bucket: clipped to burst_bytes on first use
    backlog_s: tuple[float, ...] = ()
    backlog_bytes: tuple[int, ...] = ()


@dataclass(frozen=True)
class QueueRun:
    """One call's packets, in the order given; ``n`` packets.

    departure_s : (n,) [s] when the packet left the queue; NaN when it was dropped.
    reason : (n,) int8 index into :data:`REASONS` (0: passed in time).
    depth : (n,) packets waiting when it arrived (before it joined).
    sojourn_s : (n,) [s] from arrival to departure, or to its drop (0 when refused at once).
    size_bytes : (n,) [B] with the overhead.
    """

    departure_s: Floats
    reason: Codes
    depth: Ints
    sojourn_s: Floats
    size_bytes: Ints
    state: QueueState = field(repr=False)

    @property
    def passed(self) -> npt.NDArray[np.bool_]:
        return np.asarray(self.reason == PASSED, dtype=np.bool_)


@dataclass(slots=True)
class _Waiting:
    index: int  # into this call's packets; -1 for a committed packet of an earlier call
    arrival_s: float
    size: int
    departure_s: float = math.nan  # known once it reaches the head (or committed)


class Served(NamedTuple):
    """:func:`serve_packets`'s lists, one entry per packet (see :class:`QueueRun`)."""

    departure_s: list[float]
    reason: list[int]
    depth: list[int]
    sojourn_s: list[float]
    state: QueueState


def serve_queue(
    params: QueueParams,
    arrival_s: npt.ArrayLike,
    payload_bytes: npt.ArrayLike,
    deadline_s: npt.ArrayLike | None = None,
    state: QueueState | None = None,
) -> QueueRun:
    """Serve packets through one queue in virtual time.

    Parameters
    ----------
    params : the queue.
    arrival_s : (n,) [s] arrival times, non-decreasing; ties are served in the given order.
    payload_bytes : (n,) [B] payload sizes; ``params.overhead_bytes`` is added to each.
    deadline_s : (n,) [s] or None; a packet leaving after its deadline is ``queue_late``.
    state : the queue left by the previous call (None: empty, bucket full, idle).

    Returns
    -------
    QueueRun : each packet's departure, fate, depth on arrival and sojourn; every packet of
    this call leaves or is dropped within it (the queue is drained), and ``state`` holds the
    packets that leave after the last arrival, for the next call.
    """
    arrivals = np.asarray(arrival_s, dtype=np.float64).reshape(-1)
    sizes = np.asarray(payload_bytes, dtype=np.int64).reshape(-1) + params.overhead_bytes
    n = arrivals.shape[0]
    if sizes.shape[0] != n:
        raise ValueError(f"payload_bytes has {sizes.shape[0]} entries; expected {n}")
    if n and np.any(np.diff(arrivals) < 0.0):
        raise ValueError("arrival_s must be non-decreasing")
    deadlines = (
        None if deadline_s is None else np.broadcast_to(deadline_s, (n,)).astype(float).tolist()
    )
    out = serve_packets(params, arrivals.tolist(), sizes.tolist(), deadlines, state)
    return QueueRun(
        np.array(out.departure_s, dtype=np.float64),
        np.array(out.reason, dtype=np.int8),
        np.array(out.depth, dtype=np.int64),
        np.array(out.sojourn_s, dtype=np.float64),
        sizes,
        out.state,
    )


def serve_packets(
    params: QueueParams,
    arrivals: list[float],
    sizes: list[int],
    deadlines: list[float] | None = None,
    state: QueueState | None = None,
    ready_s: float = -math.inf,
) -> Served:
    """:func:`serve_queue` on plain lists, unchecked: ``sizes`` [B] with their overhead already.

    ``ready_s`` [s]: the first packet leaves no earlier, as the one behind a head pushed out
    then (realtime's give-back, :func:`make_room`).

    A run's phases put a few packets through each queue at a time (netem, per packet of
    every phase): lists cost a tenth of arrays there.
    """
    state = state or QueueState()
    if ready_s > -math.inf:
        return _serve_many(params, arrivals, sizes, deadlines, state, ready_s)
    if state.backlog_s and arrivals and state.backlog_s[-1] <= arrivals[0]:
        # gone before the first arrival: it never sees them, nor do the clock and bucket
        state = QueueState(state.clock_s, state.tokens_bytes)
    if len(arrivals) == 1 and not state.backlog_s:
        return _serve_one(params, arrivals[0], sizes[0], deadlines, state)
    if not state.backlog_s and params.burst_bytes == 0 and arrivals[0] == arrivals[-1]:
        burst = _serve_burst(params, arrivals[0], sizes, deadlines, state)
        if burst is not None:
            return burst
    return _serve_many(params, arrivals, sizes, deadlines, state)


def _serve_burst(
    params: QueueParams,
    arrival: float,
    sizes: list[int],
    deadlines: list[float] | None,
    state: QueueState,
) -> Served | None:
    """:func:`serve_packets` of packets arriving together into an empty ``netem rate`` queue
    with room for them all (None: without it): each leaves ``8 s / r`` after the one before,
    the first after ``arrival``, as :func:`_serve_many` finds, without its queue."""
    n = len(sizes)
    if (params.limit_packets is not None and n > params.limit_packets) or (
        params.limit_bytes is not None and sum(sizes) > params.limit_bytes
    ):
        return None
    rate, t = params.rate_bps / 8.0, arrival
    departure = []
    for size in sizes:
        t = t + size / rate
        departure.append(t)
    if not departure[0] > arrival:  # the first left at once: the others see it gone
        return None
    reason = [PASSED] * n
    if deadlines is not None:
        reason = [
            QUEUE_LATE if d > due else PASSED for d, due in zip(departure, deadlines, strict=True)
        ]
    after = QueueState(t, min(state.tokens_bytes, 0.0), tuple(departure), tuple(sizes))
    return Served(departure, reason, list(range(n)), [d - arrival for d in departure], after)


def _serve_many(
    params: QueueParams,
    arrivals: list[float],
    sizes: list[int],
    deadlines: list[float] | None,
    state: QueueState,
    ready_s: float = -math.inf,
) -> Served:
    """:func:`serve_packets` in general: a FIFO of waiting packets, each leaving in turn."""
    n = len(arrivals)
    rate = params.rate_bps / 8.0  # [B/s]
    burst = float(params.burst_bytes)
    limit_packets, limit_bytes = params.limit_packets, params.limit_bytes
    clock, tokens = state.clock_s, min(state.tokens_bytes, burst)
    departure = [math.nan] * n
    reason = [PASSED] * n
    depth = [0] * n
    sojourn = [0.0] * n
    waiting: deque[_Waiting] = deque(
        _Waiting(-1, -math.inf, b, d)
        for d, b in zip(state.backlog_s, state.backlog_bytes, strict=True)
    )
    queued_bytes = sum(w.size for w in waiting)
    # when the head was last pushed out: the packet behind it is the head only from then
    head_from = ready_s

    def advance(now: float, drained: list[_Waiting] | None = None) -> None:
        """Let every packet leave that leaves at or before ``now``."""
        nonlocal clock, tokens, queued_bytes
        while waiting:
            w = waiting[0]
            if w.departure_s != w.departure_s:  # NaN: not yet computed
                start = w.arrival_s if w.arrival_s > clock else clock
                if head_from > start:
                    start = head_from
                if burst == 0.0:  # netem rate: on the wire for size / rate after the previous
                    w.departure_s = start + w.size / rate
                elif clock == -math.inf or tokens + (start - clock) * rate >= w.size:
                    w.departure_s = start  # the bucket holds its size
                else:
                    w.departure_s = clock + (w.size - tokens) / rate
            if w.departure_s > now:
                return
            waiting.popleft()
            queued_bytes -= w.size
            if drained is not None:
                drained.append(w)
            if w.index < 0:
                continue  # an earlier call's: the clock and the bucket already count it
            if burst > 0.0:
                refill = math.inf if clock == -math.inf else (w.departure_s - clock) * rate
                tokens = min(burst, tokens + refill) - w.size
            clock = w.departure_s
            departure[w.index] = w.departure_s
            sojourn[w.index] = w.departure_s - w.arrival_s
            if deadlines is not None and w.departure_s > deadlines[w.index]:
                reason[w.index] = QUEUE_LATE

    def full(size: int) -> bool:
        return (limit_packets is not None and len(waiting) + 1 > limit_packets) or (
            limit_bytes is not None and queued_bytes + size > limit_bytes
        )

    for k in range(n):
        now, size = arrivals[k], sizes[k]
        advance(now)
        depth[k] = len(waiting)
        if burst > 0.0 and size > burst:
            reason[k] = OVERSIZE
            continue
        while params.policy == "oldest" and full(size):
            victim = _oldest_droppable(waiting, now, burst, rate)
            if victim is None:
                break
            if victim is waiting[0]:  # tbf sends the next one no earlier than now
                head_from = now
            waiting.remove(victim)  # the head's departure is computed anew when it leaves
            queued_bytes -= victim.size
            reason[victim.index] = QUEUE_FULL
            sojourn[victim.index] = now - victim.arrival_s
        if full(size):
            reason[k] = QUEUE_FULL
            continue
        waiting.append(_Waiting(k, now, size))
        queued_bytes += size
    drained: list[_Waiting] = []
    advance(math.inf, drained)
    backlog = QueueState(
        clock, tokens, tuple(w.departure_s for w in drained), tuple(w.size for w in drained)
    )
    return Served(departure, reason, depth, sojourn, backlog)


def _serve_one(
    params: QueueParams,
    arrival: float,
    size: int,
    deadlines: list[float] | None,
    state: QueueState,
) -> Served:
    """:func:`serve_packets` of one packet into an empty queue (a link's queue, a phase's
    packet): the same arithmetic without the queue's bookkeeping."""
    rate, burst, clock = params.rate_bps / 8.0, float(params.burst_bytes), state.clock_s
    tokens = min(state.tokens_bytes, burst)
    refused = OVERSIZE if burst > 0.0 and size > burst else PASSED
    if not refused and params.limit_bytes is not None and size > params.limit_bytes:
        refused = QUEUE_FULL  # a limit_packets of 1 or more always has room for one
    if refused:
        return Served([math.nan], [refused], [0], [0.0], QueueState(clock, tokens))
    start = arrival if arrival > clock else clock
    if burst == 0.0:
        leaves = start + size / rate
    elif clock == -math.inf or tokens + (start - clock) * rate >= size:
        leaves = start
    else:
        leaves = clock + (size - tokens) / rate
    if burst > 0.0:
        refill = math.inf if clock == -math.inf else (leaves - clock) * rate
        tokens = min(burst, tokens + refill) - size
    late = deadlines is not None and leaves > deadlines[0]
    after = QueueState(leaves, tokens, (leaves,), (size,))  # as the queue drains it
    return Served([leaves], [QUEUE_LATE if late else PASSED], [0], [leaves - arrival], after)


def make_room(
    params: QueueParams, state: QueueState, now_s: float, size: int
) -> tuple[QueueState, list[int]]:
    """Realtime ``oldest``: the waiting packets of ``state`` that a packet of ``size`` [B] (its
    overhead included) arriving at ``now_s`` pushes out, oldest first, as :func:`serve_packets`
    pushes out the packets of its own call; the state without them, and their positions in
    ``state.backlog_s``.

    :func:`serve_packets` never takes back a packet of an earlier call (lockstep's phases are
    decided); realtime netem holds each packet until it leaves, so it can, and serves the
    packets behind it anew (``CapacityNetwork``), as :func:`serve_packets` would have.
    """
    if params.policy != "oldest" or not state.backlog_s:
        return state, []
    rate, limit_packets, limit_bytes = (
        params.rate_bps / 8.0,
        params.limit_packets,
        params.limit_bytes,
    )
    backlog = list(zip(state.backlog_s, state.backlog_bytes, strict=True))
    waiting = [j for j, (d, _) in enumerate(backlog) if d > now_s]  # not yet left
    count, queued = len(waiting), sum(backlog[j][1] for j in waiting)
    victims: list[int] = []
    for n, j in enumerate(waiting):
        full = (limit_packets is not None and count + 1 > limit_packets) or (
            limit_bytes is not None and queued + size > limit_bytes
        )
        if not full:
            break
        departure, bytes_ = backlog[j]
        if n == 0 and params.burst_bytes == 0 and departure - bytes_ / rate <= now_s:
            continue  # on the wire
        victims.append(j)
        count, queued = count - 1, queued - bytes_
    if not victims:
        return state, []
    return without(state, victims), victims


def without(state: QueueState, positions: list[int]) -> QueueState:
    """``state`` without the backlog's packets at ``positions``, its clock and bucket kept."""
    keep = [j for j in range(len(state.backlog_s)) if j not in positions]
    return QueueState(
        state.clock_s,
        state.tokens_bytes,
        tuple(state.backlog_s[j] for j in keep),
        tuple(state.backlog_bytes[j] for j in keep),
    )


def _oldest_droppable(
    waiting: deque[_Waiting], now: float, burst: float, rate: float
) -> _Waiting | None:
    """The oldest waiting packet a newer one may push out, or None."""
    for k, w in enumerate(waiting):
        if w.index < 0:
            continue  # committed by an earlier call
        on_wire = (
            k == 0
            and burst == 0.0
            and not math.isnan(w.departure_s)
            and w.departure_s - w.size / rate <= now
        )
        if not on_wire:
            return w
    return None


__all__ = [
    "OVERSIZE",
    "PASSED",
    "QUEUE_FULL",
    "QUEUE_LATE",
    "REASONS",
    "Policy",
    "QueueParams",
    "QueueRun",
    "QueueState",
    "Served",
    "make_room",
    "serve_packets",
    "serve_queue",
    "without",
]
