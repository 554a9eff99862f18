"""The layers of a netem stack: one per link model kind, each a vectorised function of keyed draws.

A layer turns the keyed uniforms of ``(links, epochs)`` into drops, states,
delays, duplicates or reorderings; ``netem.models`` gives their semantics
(MODEL.md §4, §8).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.special import ndtri

from formation.keyed_random import Stream, keyed_uniform
from formation.linkmodels import (
    Bernoulli,
    Delay,
    Down,
    Duplicate,
    GilbertElliott,
    LinkModelSpec,
    Markov4,
    Outage,
    Reorder,
    Up,
)

Bools = npt.NDArray[np.bool_]
Ints = npt.NDArray[np.int64]
Floats = npt.NDArray[np.float64]
Codes = npt.NDArray[np.int8]

MODEL_NAMES: tuple[str, ...] = (
    "up",
    "down",
    "bernoulli",
    "gilbert_elliott",
    "markov4",
    "outage",
    "delay",
    "duplicate",
    "reorder",
)
_KIND_CODE = {name: code for code, name in enumerate(MODEL_NAMES)}
_TABLE_MAX = 32767 / 8192  # tc's distribution tables are int16 scaled by NETEM_DIST_SCALE
_TABLE_MIN = -32768 / 8192


# ----------------------------------------------------------------------------- keys, chains


@dataclass(frozen=True)
class _Keys:
    """Key prefix of one or more links: ``src``, ``dst`` are ``(L, 1)``."""

    seed: int
    src: Ints
    dst: Ints

    def uniform(self, stream: Stream, kind: str, occ: int, epochs: Ints, *rest: int) -> Floats:
        """Uniforms ``(L, n)`` for ``epochs`` ``(n,)``."""
        return keyed_uniform(
            self.seed,
            int(stream),
            self.src,
            self.dst,
            _KIND_CODE[kind],
            occ,
            epochs[None, :],
            *rest,
        )

    @property
    def n_links(self) -> int:
        return int(self.src.shape[0])


def _run_chain(table: npt.NDArray[np.int64], s0: Ints) -> Ints:
    """Finite chain: ``out[:, k] = table[:, k, out[:, k-1]]`` with ``out[:, -1] = s0``.

    ``table`` is ``(L, n, S)``: the next state from each state at each step. One
    link loops in Python over lists; several links loop over epochs with numpy.
    """
    n_links, n, _ = table.shape
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


def _run_ar1(b0: float, c: float, fresh: Floats, y0: Floats) -> Floats:
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


def _table_variate(distribution: str, u: Floats) -> Floats:
    """Standardised delay variate ``Z(u)`` of tc netem's distribution tables (iproute2 ``netem/``)."""
    if distribution == "uniform":
        return 2.0 * u - 1.0
    normal = np.asarray(ndtri(u), dtype=np.float64)
    if distribution == "normal":
        return np.clip(normal, _TABLE_MIN, _TABLE_MAX)
    # pareto.c: shape a = 3, x = (1 - q)^(-1/3) has mean 1.5; the table holds (x - 1.5) * 4/3
    pareto = np.minimum((4.0 / 3.0) * (1.0 / np.cbrt(1.0 - u) - 1.5), _TABLE_MAX)
    if distribution == "pareto":
        return pareto
    # paretonormal.c: (normal + 3 pareto) / 4 on the same quantile, normal tabulated on [-10, 10]
    return np.clip((np.clip(normal, -10.0, 10.0) + 3.0 * pareto) / 4.0, _TABLE_MIN, _TABLE_MAX)


# ----------------------------------------------------------------------------- layers


@dataclass
class _Out:
    """One layer's contribution over ``(L, n)``; ``None`` where the layer has none."""

    drop: Bools | None = None
    state: Codes | None = None
    delay_epochs: Ints | None = None
    delay_ms: Floats | None = None
    dup: Bools | None = None
    reorder: Bools | None = None
    chain_prev: Floats | None = None  # delay: correlated uniform before each epoch


class _Layer:
    """One spec of a stack, as a vectorised function of keyed draws."""

    stateful = False
    timed = False
    state_names: tuple[str, ...] = ("",)

    def __init__(self, spec: LinkModelSpec, occurrence: int) -> None:
        self.spec = spec
        self.kind: str = spec.model
        self.ident = (self.kind, occurrence)
        self.occ = occurrence

    def run(self, keys: _Keys, epochs: Ints, carry: npt.NDArray[Any] | None) -> tuple[_Out, Any]:
        return _Out(), None


class _Down(_Layer):
    state_names = ("", "down")

    def run(self, keys: _Keys, epochs: Ints, carry: npt.NDArray[Any] | None) -> tuple[_Out, Any]:
        ones = np.ones((keys.n_links, epochs.shape[0]), dtype=np.bool_)
        return _Out(drop=ones, state=ones.astype(np.int8)), None


class _Outage(_Layer):
    state_names = ("", "down")

    def __init__(self, spec: Outage, occurrence: int) -> None:
        super().__init__(spec, occurrence)
        self.o = spec
        self.timed = spec.start_s is not None or spec.end_s is not None
        self.start_s = spec.start_s if spec.start_s is not None else 0.0
        self.end_s = spec.end_s if spec.end_s is not None else math.inf

    def down_at(self, time_s: Floats) -> Bools:
        return np.asarray((time_s >= self.start_s) & (time_s < self.end_s), dtype=np.bool_)

    def run(self, keys: _Keys, epochs: Ints, carry: npt.NDArray[Any] | None) -> tuple[_Out, Any]:
        o = self.o
        if self.timed:  # applied later from the packet times
            down = np.zeros(epochs.shape, dtype=np.bool_)
        elif o.end is None:
            down = epochs >= o.start
        elif o.every is None:
            down = (epochs >= o.start) & (epochs < o.end)
        else:
            down = (epochs >= o.start) & ((epochs - o.start) % o.every < o.end - o.start)
        full = np.broadcast_to(down, (keys.n_links, epochs.shape[0]))
        return _Out(drop=full, state=full.astype(np.int8)), None


class _Bernoulli(_Layer):
    def __init__(self, spec: Bernoulli, occurrence: int) -> None:
        super().__init__(spec, occurrence)
        self.p, self.c = spec.p_loss, spec.correlation
        self.stateful = self.c > 0.0

    def run(self, keys: _Keys, epochs: Ints, carry: npt.NDArray[Any] | None) -> tuple[_Out, Any]:
        u = keys.uniform(Stream.LOSS, self.kind, self.occ, epochs, 0)
        if not self.stateful:
            return _Out(drop=u < self.p), None
        if carry is None:
            carry = keys.uniform(Stream.LOSS, self.kind, self.occ, np.zeros(1, np.int64), 1)[:, 0]
        y = _run_ar1(1.0 - self.c, self.c, u, carry)
        return _Out(drop=y < self.p), y[:, -1]


class _GilbertElliott(_Layer):
    stateful = True
    state_names = ("good", "bad")

    def __init__(self, spec: GilbertElliott, occurrence: int) -> None:
        super().__init__(spec, occurrence)
        self.g = spec
        self.loss = np.array([spec.one_minus_k, spec.one_minus_h])

    def run(self, keys: _Keys, epochs: Ints, carry: npt.NDArray[Any] | None) -> tuple[_Out, Any]:
        u_move = keys.uniform(Stream.LOSS, self.kind, self.occ, epochs, 0)
        u_loss = keys.uniform(Stream.LOSS, self.kind, self.occ, epochs, 1)
        s0 = np.zeros(keys.n_links, np.int64) if carry is None else carry
        # next state from good (0): bad iff u < p; from bad (1): good iff u < r
        table = np.stack([u_move < self.g.p, u_move >= self.g.r], axis=-1).astype(np.int64)
        post = _run_chain(table, s0)
        entry = np.concatenate([s0[:, None], post[:, :-1]], axis=1)
        return _Out(drop=u_loss < self.loss[entry], state=entry.astype(np.int8)), post[:, -1]


class _Markov4(_Layer):
    stateful = True
    state_names = ("", "1", "2", "3", "4")

    def __init__(self, spec: Markov4, occurrence: int) -> None:
        super().__init__(spec, occurrence)
        self.m = spec

    def run(self, keys: _Keys, epochs: Ints, carry: npt.NDArray[Any] | None) -> tuple[_Out, Any]:
        m = self.m
        u = keys.uniform(Stream.LOSS, self.kind, self.occ, epochs)
        s0 = np.zeros(keys.n_links, np.int64) if carry is None else carry
        # states 0..3 stand for 1..4; comparisons in the order of Linux loss_4state
        from1 = np.where(u < m.p14, 3, np.where(u < m.p14 + m.p13, 2, 0))
        from2 = np.where(u < m.p23, 2, 1)
        from3 = np.where(u < m.p32, 1, np.where(u < m.p32 + m.p31, 0, 2))
        table = np.stack([from1, from2, from3, np.zeros_like(from1)], axis=-1).astype(np.int64)
        post = _run_chain(table, s0)
        return _Out(drop=post >= 2, state=(post + 1).astype(np.int8)), post[:, -1]


class _Delay(_Layer):
    def __init__(self, spec: Delay, occurrence: int) -> None:
        super().__init__(spec, occurrence)
        self.d = spec
        self.stateful = spec.correlation > 0.0

    def values(self, u: Floats) -> tuple[Ints, Floats]:
        """Delays from (correlated) uniforms ``u``: ``[epochs]`` and ``[ms]``."""
        d = self.d
        if d.jitter_epochs == 0:
            epochs = np.full(u.shape, d.epochs, dtype=np.int64)
        elif d.distribution == "uniform":
            j = d.jitter_epochs
            jitter = np.floor(u * (2 * j + 1)).astype(np.int64) - j
            epochs = np.maximum(d.epochs + jitter, 0)
        else:
            jitter = np.rint(d.jitter_epochs * _table_variate(d.distribution, u)).astype(np.int64)
            epochs = np.maximum(d.epochs + jitter, 0)
        if d.jitter_ms == 0.0:
            ms = np.full(u.shape, d.ms, dtype=np.float64)
        else:
            ms = np.maximum(d.ms + d.jitter_ms * _table_variate(d.distribution, u), 0.0)
        return epochs, ms

    def fresh(self, keys: _Keys, epochs: Ints, seq: int) -> Floats:
        return keys.uniform(Stream.DELAY, self.kind, self.occ, epochs, seq, 0)

    def run(self, keys: _Keys, epochs: Ints, carry: npt.NDArray[Any] | None) -> tuple[_Out, Any]:
        x = self.fresh(keys, epochs, 0)
        if not self.stateful:
            de, dms = self.values(x)
            return _Out(delay_epochs=de, delay_ms=dms), None
        c = self.d.correlation
        if carry is None:
            zero = np.zeros(1, np.int64)
            carry = keys.uniform(Stream.DELAY, self.kind, self.occ, zero, 0, 1)[:, 0]
        y = _run_ar1(1.0 - c, c, x, carry)
        prev = np.concatenate([carry[:, None], y[:, :-1]], axis=1)
        de, dms = self.values(y)
        return _Out(delay_epochs=de, delay_ms=dms, chain_prev=prev), y[:, -1]


class _Duplicate(_Layer):
    def __init__(self, spec: Duplicate, occurrence: int) -> None:
        super().__init__(spec, occurrence)
        self.p = spec.p

    def draw(self, keys: _Keys, epochs: Ints, seq: int) -> Bools:
        return keys.uniform(Stream.DUPLICATE, self.kind, self.occ, epochs, seq) < self.p

    def run(self, keys: _Keys, epochs: Ints, carry: npt.NDArray[Any] | None) -> tuple[_Out, Any]:
        return _Out(dup=self.draw(keys, epochs, 0)), None


class _Reorder(_Layer):
    def __init__(self, spec: Reorder, occurrence: int) -> None:
        super().__init__(spec, occurrence)
        self.p, self.gap = spec.p, spec.gap
        self.stateful = self.gap > 1

    def run(self, keys: _Keys, epochs: Ints, carry: npt.NDArray[Any] | None) -> tuple[_Out, Any]:
        hit = keys.uniform(Stream.REORDER, self.kind, self.occ, epochs) < self.p
        if not self.stateful:
            return _Out(reorder=hit), None
        top = self.gap - 1  # the counter (epochs since the last reordered one) saturates here
        count = np.zeros(keys.n_links, np.int64) if carry is None else np.minimum(carry, top)
        # state = counter; from `top` a hit resets to 0, anything else counts up to `top`
        up = np.minimum(np.arange(self.gap) + 1, top)
        table = np.broadcast_to(up, (*hit.shape, self.gap)).copy()
        table[..., top] = np.where(hit, 0, top)
        post = _run_chain(table, count)
        entry = np.concatenate([count[:, None], post[:, :-1]], axis=1)
        return _Out(reorder=(entry == top) & hit), post[:, -1]


_LAYER_OF: dict[type, type[_Layer]] = {
    Up: _Layer,
    Down: _Down,
    Bernoulli: _Bernoulli,
    GilbertElliott: _GilbertElliott,
    Markov4: _Markov4,
    Outage: _Outage,
    Delay: _Delay,
    Duplicate: _Duplicate,
    Reorder: _Reorder,
}
