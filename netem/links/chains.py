"""Markov chains and tc's correlated uniform: running them over epochs and their long-run forms.

``run_chain`` and ``run_ar1`` step many links at once (docs/model.md §4); ``cesaro`` and
``ar1_uniform_cdf`` are the long-run quantities the closed forms are built from
(docs/model.md §8). Pure array work, no draws.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

COMPILED_FROM = 1 << 18
"""Link-epochs from which :func:`run_chain` runs compiled (:mod:`netem.links.compiled_chain`)."""


def run_chain(table: npt.NDArray[np.int64], s0: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """Finite chain: ``out[:, k] = table[:, k, out[:, k-1]]`` with ``out[:, -1] = s0``.

    ``table`` is ``(L, n, S)``: the next state from each state at each step. One
    link loops in Python over lists; several links loop over epochs with numpy; and
    ``COMPILED_FROM`` link-epochs or more, one link or many, run compiled, link by link.
    """
    n_links, n, _ = table.shape
    if n_links * n >= COMPILED_FROM:
        # numba loads in about a second: only for a simulator's many links or one link's
        # long schedule (whose draws loaded it already; its Python loop made an object per
        # epoch, each collection then walking numba's too)
        from netem.links.compiled_chain import step_chains

        post = np.empty((n_links, n), dtype=np.int64)
        step_chains(table, s0.astype(np.int64), post)
        return post
    if n_links == 1:
        s = int(s0[0])
        out = []
        for row in table[0].tolist():
            s = row[s]
            out.append(s)
        return np.asarray(out, dtype=np.int64).reshape(1, n)
    post = np.empty((n_links, n), dtype=np.int64)
    rows = np.arange(n_links)
    s_vec = s0.astype(np.int64)
    for k in range(n):
        s_vec = table[rows, k, s_vec]
        post[:, k] = s_vec
    return post


def run_ar1(
    b0: float, c: float, fresh: npt.NDArray[np.float64], y0: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """tc's correlated uniform ``y[k] = b0 * fresh[k] + c * y[k-1]``, ``y[-1] = y0``; ``(L, n)``.

    The same IEEE operations in both branches, so one link and many agree bit for bit.
    """
    n_links, n = fresh.shape
    if n_links == 1:
        prev = float(y0[0])
        out = []
        for x in fresh[0].tolist():
            prev = b0 * x + c * prev
            out.append(prev)
        return np.asarray(out, dtype=np.float64).reshape(1, n)
    y = np.empty((n_links, n), dtype=np.float64)
    prev_vec = y0.astype(np.float64)
    for k in range(n):
        prev_vec = b0 * fresh[:, k] + c * prev_vec
        y[:, k] = prev_vec
    return y


def cesaro(t: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """``lim (1/n) Σ_{k<n} T^k`` by doubling (``n = 2**50``): the long-run occupancy from each state.

    Equals the stationary distribution for an irreducible chain and stays right
    for reducible or periodic ones (e.g. markov4 with ``p13 = 0``). Rows are
    renormalised at each step: repeated squaring would otherwise raise a row sum
    of ``1 - 1e-16`` to the power ``2**50``.
    """
    avg = np.eye(t.shape[0])
    power = t / t.sum(axis=1, keepdims=True)
    for _ in range(50):
        avg = 0.5 * (avg + power @ avg)
        avg /= avg.sum(axis=1, keepdims=True)
        power = power @ power
        power /= power.sum(axis=1, keepdims=True)
    return avg


def ar1_uniform_cdf(c: float, x: float) -> float:
    """``P(S < x)`` for tc's stationary correlated uniform ``S = (1 - c) Σ_i c^i U_i``.

    Each term ``w U`` is put on a grid of cell ``h = 2**-16`` and the masses are
    convolved with FFTs; terms narrower than a cell enter by their mean. Absolute
    error about ``1e-5``.
    """
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    if c == 0.0 or c >= 1.0:  # c = 1: u keeps its first value, uniform
        return x
    log2h = 16
    h = 2.0**-log2h
    n_fft = 1 << (log2h + 1)
    spectrum = np.ones(n_fft // 2 + 1, dtype=np.complex128)
    offset = -h / 2  # masses are spread over their cells, which accounts for one term's residual
    w = 1.0 - c
    while w >= h:
        cells = math.ceil(w / h)
        cdf = np.minimum(np.arange(cells + 1) * h, w) / w
        spectrum *= np.fft.rfft(np.diff(cdf), n_fft)
        offset += h / 2
        w *= c
    offset += w / (1.0 - c) / 2  # the tail Σ_{i>=M} (1-c) c^i U_i by its mean
    pmf = np.fft.irfft(spectrum, n_fft)
    t = (x - offset) / h
    j = math.floor(t)
    if j < 0:
        return 0.0
    if j >= n_fft:
        return 1.0
    return float(np.sum(pmf[:j]) + (t - j) * pmf[j])


__all__ = ["ar1_uniform_cdf", "cesaro", "run_ar1", "run_chain"]
