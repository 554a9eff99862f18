"""Reception at one receiver, compiled: ``reception.py`` and ``error_rate.py`` for the
compiled event loop (``compiled_dcf``), with the same formulas in the same order.

The floats may differ from numpy's in the last bits where numpy and the compiled code take
their ``exp``, ``log10`` and ``pow`` from different libraries, and where a matrix product
(the interference over the pieces) adds in another order; a frame's fate changes only if a
reception draw falls within those bits of its success rate (docs/model.md §11).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from formation.compiled import jit
from netem.links.wifi.error_rate import (
    CCK_SYMBOL_RATE_HZ,
    DQPSK_SCALE,
    DSSS_BANDWIDTH_HZ,
    LARGE_CHUNK_BYTES,
    LARGE_FROM_BYTES,
    NEGLIGIBLE_PER,
    OFDM_CURVES,
    SMALL_CHUNK_BYTES,
)

OFDM_RATES_KBPS = np.array(sorted(OFDM_CURVES), dtype=np.int64)
# [rate, reference (32 B, 1,458 B)] -> (low, high, c3, c2, c1, c0)
CURVES = np.array(
    [[[low, high, *coef] for low, high, coef in OFDM_CURVES[int(r)]] for r in OFDM_RATES_KBPS],
    dtype=np.float64,
)
# [rate, reference] -> the SINR (linear) below which a chunk is surely lost, above which it
# surely survives: ``_ofdm_chunk`` skips its logarithm there (a margin far above rounding)
SURE = np.array(
    [
        [
            [10.0 ** (low / 10.0) * (1.0 - 1e-9), 10.0 ** (high / 10.0) * (1.0 + 1e-9)]
            for low, high, _ in OFDM_CURVES[int(r)]
        ]
        for r in OFDM_RATES_KBPS
    ],
    dtype=np.float64,
)
_SQRT_2PI = math.sqrt(2.0 * math.pi)
_LARGE = float(LARGE_CHUNK_BYTES)
_SMALL = float(SMALL_CHUNK_BYTES)

_G = np.uint64(0x9E3779B97F4A7C15)
_C1 = np.uint64(0xBF58476D1CE4E5B9)
_C2 = np.uint64(0x94D049BB133111EB)


@jit
def _mix(z: np.uint64) -> np.uint64:
    z = (z ^ (z >> np.uint64(30))) * _C1
    z = (z ^ (z >> np.uint64(27))) * _C2
    return z ^ (z >> np.uint64(31))


_START = np.uint64(0x243F6A8885A308D3)


@jit
def _chain(h: np.uint64, key: int) -> np.uint64:
    return _mix(h + _G + _mix(np.uint64(key) + _G))


@jit
def keyed_state_of(a: int, b: int, c: int, d: int, e: int) -> np.uint64:
    """``keyed_state(a, b, c, d, e)``, bit for bit."""
    return _chain(_chain(_chain(_chain(_chain(_START, a), b), c), d), e)


@jit
def keyed_uniform_after(state: np.uint64, a: int, b: int) -> float:
    """``keyed_uniform(*prefix, a, b)`` from ``state = keyed_state(*prefix)``, bit for bit."""
    return float(_chain(_chain(state, a), b) >> np.uint64(11)) * 2.0**-53


@jit
def _ofdm_chunk(rate_kbps: int, snr: float, nbits: int) -> float:
    size = float(max(nbits // 8, 1))
    large = size >= LARGE_FROM_BYTES
    row, size_ref = np.searchsorted(OFDM_RATES_KBPS, rate_kbps), 1 if large else 0
    if snr > SURE[row, size_ref, 1]:
        return 1.0
    if snr < SURE[row, size_ref, 0]:
        return 0.0
    snr_db = 10.0 * math.log10(max(snr, 1e-30))
    low, high = CURVES[row, size_ref, 0], CURVES[row, size_ref, 1]
    if snr_db < low:
        return 0.0  # 0 to a positive power
    if snr_db > high:
        return 1.0  # 1 to any power
    x = snr_db
    c3, c2, c1, c0 = (
        CURVES[row, size_ref, 2],
        CURVES[row, size_ref, 3],
        CURVES[row, size_ref, 4],
        CURVES[row, size_ref, 5],
    )
    reference = math.exp(-math.exp(((c3 * x + c2) * x + c1) * x + c0))
    success = reference ** (size / (_LARGE if large else _SMALL))
    return 1.0 if 1.0 - success < NEGLIGIBLE_PER else success


@jit
def _ndtr(a: float) -> float:
    x = a * 0.7071067811865476
    z = abs(x)
    if z < 0.7071067811865476:
        return 0.5 + 0.5 * math.erf(x)
    y = 0.5 * math.erfc(z)
    return 1.0 - y if x > 0 else y


@jit
def _cck16_symbol_error(e2: float) -> float:
    beta = math.sqrt(2.0 * e2)
    low = max(-beta, -9.0)
    total = 0.0
    x0, y0 = 0.0, 0.0
    for k in range(401):
        x = low + (k * 0.0025) * (9.0 - low)
        y = (2.0 * _ndtr(x + beta) - 1.0) ** 7 * math.exp(-0.5 * x * x) / _SQRT_2PI
        if k > 0:
            total += (x - x0) * (y + y0) / 2.0
        x0, y0 = x, y
    return min(max(1.0 - total, 0.0), 1.0)


@jit
def _dsss_chunk(rate_kbps: int, snr: float, nbits: int) -> float:
    bits = float(nbits)
    if rate_kbps == 1000:
        ber = 0.5 * math.exp(-snr * DSSS_BANDWIDTH_HZ / 1e6)
        return float((1.0 - ber) ** bits)
    if rate_kbps == 2000:
        x = max(snr * DSSS_BANDWIDTH_HZ / 1e6 / 2.0, 1e-30)
        ber = min(DQPSK_SCALE / math.sqrt(x) * math.exp(-(2.0 - math.sqrt(2.0)) * x), 1.0)
        return float((1.0 - ber) ** bits)
    bits_per_symbol = 4 if rate_kbps == 5500 else 8
    eb_n0 = snr * DSSS_BANDWIDTH_HZ / CCK_SYMBOL_RATE_HZ / bits_per_symbol
    if bits_per_symbol == 4:
        symbol_error = _cck16_symbol_error(2.0 * eb_n0)
    else:
        symbol_error = 1.0 - (1.0 - _cck16_symbol_error(2.0 * eb_n0)) ** 2
    return float(min((1.0 - symbol_error) ** (bits / bits_per_symbol), 1.0))


@jit
def chunk_success(ofdm: bool, rate_kbps: int, snr: float, nbits: int) -> float:
    """The chance one chunk is decoded (``error_rate.chunk_success`` for one chunk)."""
    if ofdm:
        return _ofdm_chunk(rate_kbps, snr, nbits)
    return _dsss_chunk(rate_kbps, snr, nbits)


@jit
def frame_success(
    ofdm: bool,
    header: tuple[int, int, int],
    payload: tuple[int, int, int],
    bounds: npt.NDArray[np.int64],
    pieces: int,
    snr: npt.NDArray[np.float64],
    success: npt.NDArray[np.float64],
) -> None:
    """``success[r]``: the product of the chunk success rates over the header and the payload
    at receiver ``r``.

    ``header`` and ``payload`` are (from, to [ns], rate [kb/s]); ``bounds[: pieces + 1]`` the
    times the interference changes; ``snr[r, : pieces]`` the SINR over each piece (linear)."""
    for r in range(snr.shape[0]):
        p = 1.0
        for lo, hi, rate in (header, payload):
            product = 1.0
            counted = False
            for k in range(pieces):
                span = min(bounds[k + 1], hi) - max(bounds[k], lo)
                if span > 0:
                    nbits = span * rate // 1_000_000
                    product = product * chunk_success(ofdm, rate, snr[r, k], nbits)
                    counted = True
            if counted:
                p = p * product
        success[r] = p


@jit
def frame_success_alone(
    ofdm: bool,
    header: tuple[int, int, int],
    payload: tuple[int, int, int],
    start: int,
    end: int,
    snr: float,
) -> float:
    """``frame_success`` of a frame alone on the air from ``start`` to ``end`` [ns] (one
    piece at ``snr``), with the same products in the same order."""
    p = 1.0
    for lo, hi, rate in (header, payload):
        span = min(end, hi) - max(start, lo)
        if span > 0:
            p = p * (1.0 * chunk_success(ofdm, rate, snr, span * rate // 1_000_000))
    return p


__all__ = [
    "chunk_success",
    "frame_success",
    "frame_success_alone",
    "keyed_state_of",
    "keyed_uniform_after",
]
