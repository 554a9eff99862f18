"""A phase decided in one compiled call: the frames' checks, the received powers from the
positions, the event loop of ``compiled_dcf`` and the outcome's arrays.

The received power follows ``radio.received_dbm`` formula for formula (the shadowing's keyed
normal draws included), so it may differ from numpy's in the last bits only, as the loop's
reception does (docs/model.md §11). A phase's Python cost is then one call and the
``PhaseOutcome`` it builds.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from formation.compiled import jit
from netem.links.wifi.compiled_dcf import DELIVERED, LATE, run
from netem.links.wifi.compiled_medium import levels_of, timing
from netem.links.wifi.compiled_reception import keyed_state_of, keyed_uniform_after
from netem.links.wifi.config import AirConfig
from netem.links.wifi.frames import BROADCAST, Frames, PhaseOutcome
from netem.links.wifi.radio import AIR_STREAM, SHADOWING

Ints = npt.NDArray[np.int64]
Floats = npt.NDArray[np.float64]
NO_END = 1 << 62  # [ns] a phase without an end: nothing is late
# the radio's propagation, in this order
TX_DBM, REFERENCE_LOSS_DB, EXPONENT, REFERENCE_M, SIGMA_DB = range(5)
_TWO_PI = 2.0 * math.pi


@jit
def _first_bad(sender: Ints, receiver: Ints, payload_bytes: Ints, ready_ns: Ints, n: int) -> int:
    """The first rule of ``Frames.check`` a frame breaks (0 .. 3), -1 if none."""
    for f in range(sender.shape[0]):
        if sender[f] < 0 or sender[f] >= n:
            return 0
    for f in range(sender.shape[0]):
        r = receiver[f]
        if r < BROADCAST or r >= n or r == sender[f]:
            return 1
    for f in range(sender.shape[0]):
        if payload_bytes[f] < 0:
            return 2
    for f in range(sender.shape[0]):
        if ready_ns[f] < 0:
            return 3
    return -1


@jit
def _air(positions: Floats, radio: Floats, seed: int, epoch: int) -> Floats:
    """The loop's radio array (n + 2, n): rows ``[i, j]`` what ``j`` receives from ``i``
    [mW], 0 on the diagonal (``radio.received_dbm``, then to milliwatts), and two rows of
    room (``compiled_medium``)."""
    n, dims = positions.shape
    power = np.zeros((n + 2, n))
    slope = 10.0 * radio[EXPONENT]
    d0 = radio[REFERENCE_M]
    shadowed = radio[SIGMA_DB] > 0.0
    for i in range(n):
        for j in range(i + 1, n):
            square = 0.0
            for c in range(dims):
                square += (positions[i, c] - positions[j, c]) ** 2
            d = max(math.sqrt(square), d0)
            dbm = radio[TX_DBM] - (radio[REFERENCE_LOSS_DB] + slope * math.log10(d / d0))
            if shadowed:
                dbm = dbm - radio[SIGMA_DB] * _keyed_normal(seed, epoch, i, j)
            power[i, j] = power[j, i] = 10.0 ** (dbm / 10.0)
    return power


@jit
def _keyed_normal(seed: int, epoch: int, i: int, j: int) -> float:
    """``keyed_normal(seed, AIR_STREAM, SHADOWING, epoch, i, j)`` (Box–Muller)."""
    state = keyed_state_of(seed, AIR_STREAM, SHADOWING, epoch, i)
    u1 = keyed_uniform_after(state, j, 0)
    u2 = keyed_uniform_after(state, j, 1)
    return math.sqrt(-2.0 * math.log1p(-u1)) * math.cos(_TWO_PI * u2)


@jit
def _phase(
    positions: Floats,
    sender: Ints,
    receiver: Ints,
    payload_bytes: Ints,
    ready_ns: Ints,
    radio: Floats,
    levels: Floats,
    t: Ints,
    seed: int,
    epoch: int,
    phase: int,
    end_ns: int,
) -> tuple[int, npt.NDArray[np.bool_], Ints, npt.NDArray[np.int8], Ints, Ints, int]:
    """The checks, the powers, the loop and the outcome: (the first broken rule or -1,
    delivered, arrival [ns], cause, attempts, first start [ns], when the medium fell silent
    [ns]); frames received after ``end_ns`` are late."""
    n, m = positions.shape[0], sender.shape[0]
    bad = _first_bad(sender, receiver, payload_bytes, ready_ns, n)
    if bad >= 0:
        empty = np.zeros((0, 0), dtype=np.int64)
        none = np.zeros(0, dtype=np.int64)
        return bad, empty == 0, empty, empty.astype(np.int8), none, none, 0
    frames = np.empty((m, 4), dtype=np.int64)
    for f in range(m):
        frames[f, 0], frames[f, 1] = sender[f], receiver[f]
        frames[f, 2], frames[f, 3] = payload_bytes[f], ready_ns[f]
    out, extra, silent = run(
        frames, _air(positions, radio, seed, epoch), levels, t, seed, epoch, phase
    )
    arrival = out[:m]
    cause = np.empty((m, n), dtype=np.int8)
    delivered = np.empty((m, n), dtype=np.bool_)
    for f in range(m):
        for j in range(n):
            c = out[m + f, j]
            if c == DELIVERED and arrival[f, j] > end_ns:
                c = LATE
            cause[f, j] = c
            delivered[f, j] = c == DELIVERED
    return -1, delivered, arrival, cause, extra[:, 0].copy(), extra[:, 1].copy(), silent


_ARRAYS: dict[int, tuple[AirConfig, Floats, Floats, Ints]] = {}


def _arrays_of(config: AirConfig) -> tuple[Floats, Floats, Ints]:
    """The config's radio, levels and timing as arrays, kept per config object (a frozen
    model's hash costs more than the lookup)."""
    kept = _ARRAYS.get(id(config))
    if kept is None or kept[0] is not config:
        if len(_ARRAYS) >= 64:
            _ARRAYS.clear()
        radio = np.array(
            [
                config.tx_power_dbm,
                config.reference_loss_db,
                config.path_loss_exponent,
                config.reference_distance_m,
                config.shadowing_sigma_db,
            ]
        )
        kept = (config, radio, levels_of(config), timing(config))
        _ARRAYS[id(config)] = kept
    return kept[1], kept[2], kept[3]


def decide(
    config: AirConfig,
    positions_m: Floats,
    frames: Frames,
    seed: int,
    epoch: int,
    phase: int,
    phase_end_ns: int | None,
) -> PhaseOutcome:
    """``dcf.decide_phase`` through one compiled call; ``AirError`` for a frame that does not
    fit the team (``Frames.check``)."""
    positions = np.ascontiguousarray(positions_m, dtype=np.float64)
    radio, levels, t = _arrays_of(config)
    bad, delivered, arrival, cause, attempts, first_start, end_ns = _phase(
        positions,
        frames.sender,
        frames.receiver,
        frames.payload_bytes,
        frames.ready_ns,
        radio,
        levels,
        t,
        seed,
        epoch,
        phase,
        NO_END if phase_end_ns is None else phase_end_ns,
    )
    if bad >= 0:
        frames.check(positions.shape[0])  # raises the error naming the frame
    return PhaseOutcome(delivered, arrival, cause, attempts, first_start, end_ns)


__all__ = ["decide"]
