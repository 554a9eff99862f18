"""The chance a stretch of a frame at one SINR is decoded: the PHY's chunk success rate.

As ns-3.44's ``InterferenceHelper`` (docs/model.md §11): a frame at a receiver is cut into
chunks wherever the interference changes, and each chunk of ``nbits`` at SINR ``γ`` survives
with the chunk success rate of the mode it is sent in; the frame survives with the product.

- **OFDM** (``ofdm``, ``erp_ofdm``): ns-3's default ``TableBasedErrorRateModel`` (AWGN, BCC)
  gives the error rate ``PER_ref(γ)`` of a 32 B frame (chunks under 400 B) or a 1,458 B one,
  and scales it to a chunk of ``b = max(1, ⌊nbits/8⌋)`` bytes as
  ``1 − (1 − PER_ref)^(b / ref)`` (IEEE 802.11-14/0803r1); rates under 10⁻⁵ count as 0. Here
  ``ln(−ln(1 − PER_ref))`` is a cubic in the SINR [dB], fitted per rate and reference (least
  squares on the success rate) to ns-3's model sampled every 0.05 dB (``python -m
  testkit.ns3_air --error-rates``); below its range a chunk is lost, above it kept. The fit is
  within 0.033 of ns-3's success rate for chunks of 32 B and more (chunks of a few bytes, at
  the very bottom of a range, up to 0.5).
- **DSSS**: ns-3's ``DsssErrorRateModel``: DBPSK at 1 Mb/s, bit error ``½ e^(−Eb/N0)``; DQPSK at
  2 Mb/s (its approximation); CCK at 5.5 and 11 Mb/s from the symbol error of 16-ary
  bi-orthogonal signalling, an integral computed here on a fixed grid; ``Eb/N0 = γ · 22 MHz /
  the bit rate's symbol rate``.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from scipy.special import ndtr

Floats = npt.NDArray[np.float64]
Ints = npt.NDArray[np.int64]

SMALL_CHUNK_BYTES = 32  # ns-3's reference frames, and the size from which the large one is used
LARGE_CHUNK_BYTES = 1458
LARGE_FROM_BYTES = 400
NEGLIGIBLE_PER = 1e-5
DQPSK_SCALE = (math.sqrt(2.0) + 1.0) / math.sqrt(8.0 * math.pi * math.sqrt(2.0))  # ns-3's DQPSK BER

# per OFDM rate [kb/s]: for the 32 B and 1,458 B references, (lowest, highest SINR [dB] of the
# fit, cubic coefficients of ln(−ln(1 − PER)) in the SINR [dB], highest power first)
Curve = tuple[float, float, tuple[float, float, float, float]]
OFDM_CURVES: dict[int, tuple[Curve, Curve]] = {
    6000: (
        (-3.45, 2.4, (-0.0429286, -0.521917, -2.73463, -3.20558)),
        (-0.95, 2.95, (0.298545, -0.885082, -2.39068, 0.433751)),
    ),
    9000: (
        (-3.25, 4.75, (-0.0110088, -0.141725, -1.37705, -0.271879)),
        (0.4, 5.65, (-0.0174932, -0.112988, -1.42232, 3.57295)),
    ),
    12000: (
        (-0.45, 5.3, (-0.0549205, -0.0423284, -0.996569, 1.65128)),
        (2.05, 5.95, (0.161156, -2.1273, 6.10849, -3.1525)),
    ),
    18000: (
        (2.05, 7.9, (-0.0231592, -0.0580674, 0.0349048, 2.17638)),
        (4.55, 8.85, (-0.0588672, 0.511187, -2.50557, 8.40383)),
    ),
    24000: (
        (4.05, 11.3, (-0.00849942, -0.0629986, 0.694438, 0.716801)),
        (7.55, 12.35, (0.056187, -1.85783, 17.4828, -48.3511)),
    ),
    36000: (
        (8.05, 14.4, (-0.0680262, 1.82992, -17.4963, 59.8606)),
        (11.05, 15.4, (-0.0569304, 1.86983, -22.5928, 99.9322)),
    ),
    48000: (
        (11.55, 19.2, (-0.0184479, 0.597058, -7.10921, 32.8198)),
        (14.55, 20.2, (0.0440112, -2.37258, 40.1761, -215.647)),
    ),
    54000: (
        (13.05, 20.2, (-0.0368378, 1.48753, -20.8595, 102.645)),
        (16.05, 21.2, (0.0233096, -1.46703, 27.8791, -163.834)),
    ),
}

DSSS_BANDWIDTH_HZ = 22e6
CCK_SYMBOL_RATE_HZ = 1.375e6


def _reference_success(curve: Curve, snr_db: Floats) -> Floats:
    low, high, (c3, c2, c1, c0) = curve
    x = np.clip(snr_db, low, high)
    with np.errstate(over="ignore"):
        success = np.exp(-np.exp(((c3 * x + c2) * x + c1) * x + c0))
    success[snr_db < low] = 0.0
    success[snr_db > high] = 1.0
    return np.asarray(success, dtype=np.float64)


def ofdm_success(rate_kbps: int, snr: Floats, nbits: Ints) -> Floats:
    """Chunk success rates of an OFDM rate: ``snr`` linear, ``nbits`` per chunk (same shape)."""
    snr_db = 10.0 * np.log10(np.maximum(snr, 1e-30))
    size = np.maximum(nbits // 8, 1).astype(np.float64)
    small, large = OFDM_CURVES[rate_kbps]
    is_large = size >= LARGE_FROM_BYTES
    ref_bytes: float | Floats
    if not is_large.any():
        reference, ref_bytes = _reference_success(small, snr_db), float(SMALL_CHUNK_BYTES)
    elif is_large.all():
        reference, ref_bytes = _reference_success(large, snr_db), float(LARGE_CHUNK_BYTES)
    else:
        reference = np.where(
            is_large, _reference_success(large, snr_db), _reference_success(small, snr_db)
        )
        ref_bytes = np.where(is_large, float(LARGE_CHUNK_BYTES), float(SMALL_CHUNK_BYTES))
    with np.errstate(divide="ignore"):
        success = np.power(reference, size / ref_bytes)
    return np.asarray(np.where(1.0 - success < NEGLIGIBLE_PER, 1.0, success), dtype=np.float64)


def _cck16_symbol_error(e2: Floats) -> Floats:
    """Symbol error of 16-ary bi-orthogonal signalling at symbol energy over noise ``e2``:
    ``1 − ∫_{−β}^{∞} (2Φ(x + β) − 1)^7 φ(x) dx``, ``β = √(2 e2)``."""
    beta = np.sqrt(2.0 * np.asarray(e2, dtype=np.float64))[..., None]
    low = np.maximum(-beta, -9.0)  # φ is below 1e-18 beyond ±9
    x = low + np.linspace(0.0, 1.0, 401) * (9.0 - low)
    y = (2.0 * ndtr(x + beta) - 1.0) ** 7 * np.exp(-0.5 * x * x) / math.sqrt(2.0 * math.pi)
    integral = np.trapezoid(y, x, axis=-1)
    return np.asarray(np.clip(1.0 - integral, 0.0, 1.0), dtype=np.float64)


def dsss_success(rate_kbps: int, snr: Floats, nbits: Ints) -> Floats:
    """Chunk success rates of a DSSS rate: ``snr`` linear, ``nbits`` per chunk (same shape)."""
    bits = nbits.astype(np.float64)
    if rate_kbps == 1000:
        ber = 0.5 * np.exp(-snr * DSSS_BANDWIDTH_HZ / 1e6)
        return np.asarray((1.0 - ber) ** bits, dtype=np.float64)
    if rate_kbps == 2000:
        x = np.maximum(snr * DSSS_BANDWIDTH_HZ / 1e6 / 2.0, 1e-30)
        ber = np.minimum(DQPSK_SCALE / np.sqrt(x) * np.exp(-(2.0 - math.sqrt(2.0)) * x), 1.0)
        return np.asarray((1.0 - ber) ** bits, dtype=np.float64)
    bits_per_symbol = 4 if rate_kbps == 5500 else 8
    eb_n0 = snr * DSSS_BANDWIDTH_HZ / CCK_SYMBOL_RATE_HZ / bits_per_symbol
    if bits_per_symbol == 4:
        symbol_error = _cck16_symbol_error(2.0 * eb_n0)
    else:
        symbol_error = 1.0 - (1.0 - _cck16_symbol_error(2.0 * eb_n0)) ** 2
    success = (1.0 - symbol_error) ** (bits / bits_per_symbol)
    return np.asarray(np.minimum(success, 1.0), dtype=np.float64)


def chunk_success(ofdm: bool, rate_kbps: int, snr: Floats, nbits: Ints) -> Floats:
    """The chance each chunk is decoded: ``snr`` linear, ``nbits`` per chunk (same shape)."""
    snr = np.asarray(snr, dtype=np.float64)
    nbits = np.asarray(nbits, dtype=np.int64)
    if ofdm:
        return ofdm_success(rate_kbps, snr, nbits)
    return dsss_success(rate_kbps, snr, nbits)


__all__ = ["OFDM_CURVES", "chunk_success", "dsss_success", "ofdm_success"]
