"""What netem does to each packet of a directed link: pass, drop, delay, duplicate, reorder.

The functional core of netem (ARCHITECTURE.md "Time"; MODEL.md §4, §8): numpy in,
numpy out, no clocks, no Zenoh, no global random state. Every draw comes from
``formation.keyed_random`` keyed by ``(seed, stream, src, dst, kind, occurrence,
epoch[, seq], slot)``, so a decision depends only on its key: any process, asking
epochs in any order, gets the same answer, and the in-process simulator
(``delivery_matrix``) gets the same numbers as the netem process (``LinkModel``).

Semantics (tc netem's where it has them, see ``man tc-netem`` and Linux
``net/sched/sch_netem.c``):

* **A stack** of specs is applied in order. Loss layers (up, down, bernoulli,
  gilbert_elliott, markov4, outage) each decide independently; a packet is
  dropped when any of them drops it, and ``Decision.model`` names the first one
  in stack order that did. Every layer's chain runs whether or not another layer
  dropped the packet, so adding an outage on top of a Bernoulli loss leaves the
  Bernoulli decisions outside the window unchanged (draws are keyed by the
  layer's kind and its occurrence among layers of that kind, not by position).
* **Loss is per epoch.** A link is healthy or not at an epoch (MODEL.md §4): all
  packets of one epoch on one link share the loss verdict and the Markov state;
  chains step once per epoch. **Delay and duplication are per packet**, keyed by
  ``(epoch, seq)`` where ``seq`` is the index of the packet among the link's
  packets of that epoch (0 for the first; the lockstep protocol sends one), not
  the publisher's wire sequence number, which the simulator does not have.
* **Gilbert–Elliott** (tc ``loss gemodel p r 1-h 1-k``): the packet of epoch
  ``k`` is lost with the loss probability of the state the chain is in when it
  arrives (``1-k`` good, ``1-h`` bad), then the chain moves (``p`` good→bad,
  ``r`` bad→good); it starts good. ``state`` reports that entry state.
* **Four-state** (tc ``loss state p13 p31 p32 p23 p14``), states numbered as the
  parameter names number them (Salsano et al.'s GI model; in Linux
  ``loss_4state`` 1 = ``TX_IN_GAP_PERIOD``, 2 = ``TX_IN_BURST_PERIOD``, 3 =
  ``LOST_IN_BURST_PERIOD``, 4 = ``LOST_IN_GAP_PERIOD``, whatever the kernel's enum
  values): 1 good reception, 2 reception inside a burst, 3 loss inside a burst,
  4 isolated loss. Per packet the chain first moves (1→4 w.p. ``p14``, 1→3 w.p.
  ``p13``; 2→3 w.p. ``p23``; 3→2 w.p. ``p32``, 3→1 w.p. ``p31``; 4→1 always),
  then the packet is lost iff the new state is 3 or 4. The chain starts in 1.
  (Note: the docstring of ``formation.linkmodels.Markov4`` swaps the names of
  states 2 and 3; the transition names follow the kernel, as here.)
* **Bernoulli** with ``correlation`` ``c`` uses tc's correlated uniform
  ``u[k] = (1 - c) fresh[k] + c u[k-1]`` (``u[-1]`` a keyed draw) and drops when
  ``u[k] < p_loss``; its stationary loss rate is far below ``p_loss`` for
  ``c > 0`` (``expected_loss_rate`` computes it).
* **Outage** drops in ``[start, end)`` epochs (repeating every ``every``
  epochs). With ``start_s``/``end_s`` it is a realtime window in seconds instead:
  its epoch fields are ignored, and ``decide`` needs ``time_s`` (seconds since
  the run started); such a window does not repeat.
* **Delay**: lockstep ``delay_epochs = max(0, epochs + J)``, with ``J`` uniform
  on the integers ``-j..j`` (``distribution = "uniform"``) or
  ``round(j * Z)``; realtime ``delay_ms = max(0, ms + jitter_ms * Z)``, with
  ``Z = 2u - 1`` (uniform) or the continuous inverse of tc's tables (normal;
  pareto with shape 3, centred and scaled by 4/3; paretonormal = (normal + 3
  pareto) / 4 on one quantile), clipped to the tables' int16 range. Correlation
  ``c`` runs tc's correlated uniform over epochs (packets with ``seq > 0`` use
  ``(1 - c) fresh + c u[k-1]``). Several delay layers add up.
* **Duplicate** adds a copy w.p. ``p`` to a delivered packet; both copies share
  the delay. Unlike tc, a dropped packet is dropped whole, so loss rates keep
  their closed forms.
* **Reorder** (tc ``reorder P gap N``): once ``N - 1`` epochs have passed since
  the last reordered one, each epoch's packets skip all delay of the stack with
  probability ``P`` (``gap = 1``: every epoch independently; ``P = 1``: every
  ``N``-th epoch). Unlike tc, the counter counts epochs, dropped or not, so
  layers stay independent.
* ``verdict``: ``"drop"``; else ``"duplicate"`` when ``copies > 1``; else
  ``"delayed"`` when ``delay_epochs > 0`` or ``delay_ms > 0``; else ``"pass"``.

Run-time change (``LinkModel.replace``): the stack in force at epoch ``k`` is the
latest one given with ``from_epoch <= k``. A stateful layer of the new stack
continues the state of the old stack's layer of the same kind and occurrence (a
Gilbert–Elliott replaced by another Gilbert–Elliott keeps its good/bad state; its
draws stay the same keyed numbers), otherwise it starts in its initial state.

Cost: ``LinkModel.decide`` computes blocks of epochs with the vectorised form
(the same code as ``schedule``), checkpoints the chains at block starts and
serves decisions from a small cache, about a million decisions per second per
link; ``bench/bench_netem_models.py`` measures it.

References: Linux ``net/sched/sch_netem.c`` (``loss_4state``,
``loss_gilb_ell``, ``get_crandom``, ``tabledist``, ``netem_enqueue``); iproute2
``tc/q_netem.c`` (``1-h`` is sent to the kernel as ``h``) and
``netem/{normal,pareto,paretonormal}.c``; S. Salsano, F. Ludovici, A. Ordine,
"Definition of a general and intuitive loss model for packet networks and its
implementation in the Netem module in the Linux kernel" (NetemCLG).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt
from scipy.special import ndtri

from formation.errors import TestbedError
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
Carry = dict[tuple[str, int], npt.NDArray[Any]]

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
_KEY_LIMIT = 2**63


class LinkModelError(TestbedError):
    """A link model that cannot be built or asked: names the link and the broken rule."""

    def __init__(self, link: str, problem: str) -> None:
        self.link, self.problem = link, problem
        super().__init__(f"link {link}: {problem}")


class Decision(NamedTuple):
    """What netem does with one packet (one link, one epoch, one ``seq``)."""

    delivered: bool
    delay_epochs: int  # [epochs] lockstep
    delay_ms: float  # [ms] realtime
    copies: int  # 0 dropped, 1, 2 when duplicated
    verdict: str  # "pass" | "drop" | "duplicate" | "delayed"
    model: str  # the model that dropped the packet, "" when delivered
    state: str  # e.g. "bad", "3", "down"; layers' states joined by ","; "" when none
    reordered: bool = False  # skipped the stack's delay


@dataclass(frozen=True)
class Schedule:
    """Decisions of one link over consecutive epochs (``seq = 0``); arrays of shape ``(n,)``.

    ``state_codes`` and ``layer_kinds`` are ``(n, w)``: per stack layer, its state
    code (gilbert_elliott 0 good / 1 bad; markov4 1..4; outage and down 1 when
    down; else 0) and its kind as an index into ``MODEL_NAMES``; ``-1`` pads
    stacks shorter than ``w``. ``drop_model`` is the ``MODEL_NAMES`` index of the
    model that dropped, ``-1`` when delivered.
    """

    epochs: Ints
    delivered: Bools
    copies: npt.NDArray[np.int8]
    delay_epochs: Ints
    delay_ms: Floats
    reordered: Bools
    drop_model: Codes
    state_codes: Codes
    layer_kinds: Codes

    def __len__(self) -> int:
        return int(self.epochs.shape[0])

    def decision(self, i: int) -> Decision:
        """The decision at index ``i`` (epoch ``epochs[i]``), as ``LinkModel.decide`` gives it."""
        kinds = [k for k in self.layer_kinds[i].tolist() if k >= 0]
        codes = self.state_codes[i].tolist()[: len(kinds)]
        dm = int(self.drop_model[i])
        return _make_decision(
            MODEL_NAMES[dm] if dm >= 0 else "",
            int(self.copies[i]),
            int(self.delay_epochs[i]),
            float(self.delay_ms[i]),
            bool(self.reordered[i]),
            _state_string([MODEL_NAMES[k] for k in kinds], codes),
        )

    def state_of(self, model: str, occurrence: int = 0) -> Codes:
        """State codes ``(n,)`` of the ``occurrence``-th layer of kind ``model``; -1 where absent."""
        kind = _KIND_CODE[model]
        is_kind = self.layer_kinds == kind
        rank = np.cumsum(is_kind, axis=1) - 1
        hit = is_kind & (rank == occurrence)
        found = hit.any(axis=1)
        col = np.argmax(hit, axis=1)
        codes = self.state_codes[np.arange(len(self)), col]
        return np.where(found, codes, -1).astype(np.int8)


@dataclass(frozen=True)
class LinkMatrix:
    """Decisions of ``L`` links over ``n`` epochs (``seq = 0``); every array is ``(n, L)``."""

    delivered: Bools
    copies: npt.NDArray[np.int8]
    delay_epochs: Ints
    delay_ms: Floats
    reordered: Bools


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


@dataclass(frozen=True)
class _Stack:
    specs: tuple[LinkModelSpec, ...]
    layers: tuple[_Layer, ...]

    @property
    def stateful(self) -> bool:
        return any(layer.stateful for layer in self.layers)

    @property
    def timed(self) -> tuple[int, ...]:
        return tuple(i for i, layer in enumerate(self.layers) if layer.timed)


def _build_stack(specs: Sequence[LinkModelSpec], link: str) -> _Stack:
    layers: list[_Layer] = []
    seen: dict[str, int] = {}
    for i, spec in enumerate(specs):
        cls = _LAYER_OF.get(type(spec))
        if cls is None:
            raise LinkModelError(link, f"stack[{i}] = {spec!r}; expected a LinkModelSpec")
        if isinstance(spec, Markov4) and spec.p13 + spec.p14 > 1.0:
            raise LinkModelError(
                link, f"stack[{i}] markov4 has p13 + p14 = {spec.p13 + spec.p14:g}; expected <= 1"
            )
        if isinstance(spec, Markov4) and spec.p31 + spec.p32 > 1.0:
            raise LinkModelError(
                link, f"stack[{i}] markov4 has p31 + p32 = {spec.p31 + spec.p32:g}; expected <= 1"
            )
        occ = seen.get(spec.model, 0)
        seen[spec.model] = occ + 1
        layers.append(cls(spec, occ))
    return _Stack(tuple(specs), tuple(layers))


# ----------------------------------------------------------------------------- one run of a stack


@dataclass
class _Piece:
    """A stack run over epochs ``start .. start + n - 1`` for ``L`` links (raw, before drops)."""

    start: int
    stack: _Stack
    first: npt.NDArray[np.int16]  # (L, n) first dropping layer, -1 none
    dup: npt.NDArray[np.int8]  # (L, n) extra copies
    delay_epochs: Ints  # (L, n) summed over delay layers
    delay_ms: Floats
    reorder: Bools
    states: Codes  # (L, n, len(layers))
    chain_prev: dict[int, Floats] = field(default_factory=dict)

    @property
    def n(self) -> int:
        return int(self.first.shape[1])

    def apply_times(self, time_s: Floats) -> None:
        """Drop by the realtime outage windows at packet times ``time_s`` ``(n,)`` [s]."""
        for i in self.stack.timed:
            layer = self.stack.layers[i]
            assert isinstance(layer, _Outage)
            down = np.broadcast_to(layer.down_at(time_s), self.first.shape)
            self.first = np.where(down & ((self.first < 0) | (self.first > i)), i, self.first)
            self.first = self.first.astype(np.int16)
            self.states[:, :, i] = down

    def final(self) -> tuple[Bools, npt.NDArray[np.int8], Ints, Floats, Bools]:
        """``delivered, copies, delay_epochs, delay_ms, reordered``, each ``(L, n)``."""
        delivered = self.first < 0
        copies = np.where(delivered, 1 + self.dup, 0).astype(np.int8)
        reordered = delivered & self.reorder
        delayed = delivered & ~self.reorder
        return (
            delivered,
            copies,
            np.where(delayed, self.delay_epochs, 0),
            np.where(delayed, self.delay_ms, 0.0),
            reordered,
        )


def _run_stack(
    stack: _Stack, keys: _Keys, start: int, n: int, carry: Carry
) -> tuple[_Piece, Carry]:
    epochs = np.arange(start, start + n, dtype=np.int64)
    shape = (keys.n_links, n)
    first = np.full(shape, -1, dtype=np.int16)
    dup = np.zeros(shape, dtype=np.int8)
    delay_epochs = np.zeros(shape, dtype=np.int64)
    delay_ms = np.zeros(shape, dtype=np.float64)
    reorder = np.zeros(shape, dtype=np.bool_)
    states = np.zeros((*shape, len(stack.layers)), dtype=np.int8)
    drops: list[tuple[int, Bools]] = []
    chain_prev: dict[int, Floats] = {}
    after: Carry = {}
    for i, layer in enumerate(stack.layers):
        out, end = layer.run(keys, epochs, carry.get(layer.ident))
        if end is not None:
            after[layer.ident] = end
        if out.drop is not None:
            drops.append((i, out.drop))
        if out.state is not None:
            states[:, :, i] = out.state
        if out.delay_epochs is not None and out.delay_ms is not None:
            delay_epochs += out.delay_epochs
            delay_ms += out.delay_ms
        if out.dup is not None:
            dup += out.dup.astype(np.int8)
        if out.reorder is not None:
            reorder |= out.reorder
        if out.chain_prev is not None:
            chain_prev[i] = out.chain_prev
    for i, drop in reversed(drops):
        first = np.where(drop, np.int16(i), first).astype(np.int16)
    piece = _Piece(start, stack, first, dup, delay_epochs, delay_ms, reorder, states, chain_prev)
    return piece, after


def _state_string(kinds: Sequence[str], codes: Sequence[int]) -> str:
    names = []
    for kind, code in zip(kinds, codes, strict=False):
        name = _STATE_NAMES[kind][code] if code >= 0 else ""
        if name:
            names.append(name)
    return ",".join(names)


_STATE_NAMES = {name: ("",) for name in MODEL_NAMES} | {
    "down": _Down.state_names,
    "outage": _Outage.state_names,
    "gilbert_elliott": _GilbertElliott.state_names,
    "markov4": _Markov4.state_names,
}


def _make_decision(
    model: str, copies: int, delay_epochs: int, delay_ms: float, reordered: bool, state: str
) -> Decision:
    if model:
        return Decision(False, 0, 0.0, 0, "drop", model, state, False)
    if copies > 1:
        verdict = "duplicate"
    elif delay_epochs > 0 or delay_ms > 0.0:
        verdict = "delayed"
    else:
        verdict = "pass"
    return Decision(True, delay_epochs, delay_ms, copies, verdict, "", state, reordered)


def _check_key(link: str, name: str, value: int) -> None:
    if not 0 <= value < _KEY_LIMIT:
        raise LinkModelError(link, f"{name} = {value}; expected an integer in [0, 2**63)")


# ----------------------------------------------------------------------------- one link


@dataclass
class _Block:
    """Decisions of epochs ``start .. start + block - 1`` (``seq = 0``, no realtime windows)."""

    start: int
    pieces: list[_Piece]
    decisions: list[Decision]
    timed: bool
    by_seq: dict[tuple[int, int], tuple[list[int], list[int], list[float]]] = field(
        default_factory=dict
    )  # (piece, seq) → extra copies, delay [epochs], delay [ms] of packet `seq` of each epoch


class LinkModel:
    """Decisions of one directed link ``src → dst`` (MODEL.md §4; ARCHITECTURE.md "Time").

    Parameters
    ----------
    specs : sequence of LinkModelSpec
        The stack, applied in order (see the module docstring).
    seed : int
        The run's seed, in ``[0, 2**63)``.
    src, dst : int
        Link endpoints: agents ``1..n``, the leader ``0``.
    block_epochs : int
        Decisions are computed vectorised in blocks of this many epochs and
        served from a cache; Markov state is checkpointed at block starts.
    cache_blocks : int
        How many blocks of decisions to keep.
    """

    def __init__(
        self,
        specs: Sequence[LinkModelSpec],
        seed: int,
        src: int,
        dst: int,
        *,
        block_epochs: int = 1024,
        cache_blocks: int = 8,
    ) -> None:
        self.link = f"{src}→{dst}"
        for name, value in (("seed", seed), ("src", src), ("dst", dst)):
            _check_key(self.link, name, value)
        if block_epochs < 1 or cache_blocks < 1:
            raise LinkModelError(
                self.link,
                f"block_epochs = {block_epochs}, cache_blocks = {cache_blocks}; expected >= 1",
            )
        self.seed, self.src, self.dst = seed, src, dst
        self._keys = _Keys(seed, np.array([[src]], np.int64), np.array([[dst]], np.int64))
        self._b = block_epochs
        self._cache_blocks = cache_blocks
        self._timeline: list[tuple[int, _Stack]] = [(0, _build_stack(specs, self.link))]
        self._carries: dict[int, Carry] = {0: {}}
        self._blocks: dict[int, _Block] = {}

    def __repr__(self) -> str:
        changes = ", ".join(f"{f}: {list(s.specs)!r}" for f, s in self._timeline)
        return f"LinkModel({self.link}, seed={self.seed}, stacks={{{changes}}})"

    @property
    def specs(self) -> tuple[LinkModelSpec, ...]:
        """The latest stack given (in force from its ``from_epoch`` on)."""
        return self._timeline[-1][1].specs

    @property
    def timeline(self) -> tuple[tuple[int, tuple[LinkModelSpec, ...]], ...]:
        """Every stack with the epoch it starts at, ``((0, specs), (from_epoch, specs), ...)``."""
        return tuple((f, s.specs) for f, s in self._timeline)

    def specs_at(self, epoch: int) -> tuple[LinkModelSpec, ...]:
        """The stack in force at ``epoch``."""
        return self._stack_at(epoch).specs

    def replace(self, specs: Sequence[LinkModelSpec], from_epoch: int) -> None:
        """Use ``specs`` from ``from_epoch`` on; decisions before it stay what they were.

        Later changes already given are superseded. Stateful layers carry their
        state into a layer of the same kind and occurrence (module docstring).
        """
        _check_key(self.link, "from_epoch", from_epoch)
        stack = _build_stack(specs, self.link)
        kept = [(f, s) for f, s in self._timeline if f < from_epoch]  # the first starts at 0
        self._timeline = [*kept, (from_epoch, stack)]
        k = from_epoch // self._b
        self._blocks = {i: blk for i, blk in self._blocks.items() if i < k}
        self._carries = {i: c for i, c in self._carries.items() if i <= k}

    def decide(self, epoch: int, seq: int = 0, time_s: float | None = None) -> Decision:
        """The decision for packet ``seq`` of ``epoch`` (realtime windows at ``time_s`` [s]).

        The same answer for the same arguments, in any order of calls, in any process.
        """
        blk = self._blocks.get(epoch // self._b)
        if blk is None:
            if epoch < 0:
                raise LinkModelError(self.link, f"epoch = {epoch}; expected >= 0")
            blk = self._block(epoch // self._b)
        if seq == 0 and not blk.timed:
            return blk.decisions[epoch - blk.start]
        return self._decide_slow(blk, epoch, seq, time_s)

    def schedule(
        self, n_epochs: int, start: int = 0, times_s: npt.ArrayLike | None = None
    ) -> Schedule:
        """Decisions of epochs ``start .. start + n_epochs - 1`` (``seq = 0``) as arrays.

        ``times_s`` ``(n_epochs,)`` [s]: packet times, needed when a realtime outage is in force.
        """
        if n_epochs < 0 or start < 0:
            raise LinkModelError(
                self.link, f"start = {start}, n_epochs = {n_epochs}; expected >= 0"
            )
        k = start // self._b
        carry = self._carry_at(k)
        pieces, _ = self._run_range(k * self._b, start + n_epochs, carry)
        pieces = _trim(pieces, start)
        if times_s is not None:
            times = np.asarray(times_s, dtype=np.float64)
            if times.shape != (n_epochs,):
                raise LinkModelError(
                    self.link, f"times_s has shape {times.shape}; expected ({n_epochs},)"
                )
            for p in pieces:
                p.apply_times(times[p.start - start : p.start - start + p.n])
        else:
            self._require_times(pieces)
        return _schedule_of(pieces, start, n_epochs)

    # internals ----------------------------------------------------------------------------------

    def _stack_at(self, epoch: int) -> _Stack:
        stack = self._timeline[0][1]
        for f, s in self._timeline:
            if f <= epoch:
                stack = s
        return stack

    def _run_range(self, a: int, b: int, carry: Carry) -> tuple[list[_Piece], Carry]:
        """Run epochs ``a .. b - 1`` from ``carry``, split where the stack changes."""
        cuts = sorted({a, b, *(f for f, _ in self._timeline if a < f < b)})
        pieces = []
        for s, e in itertools.pairwise(cuts):
            stack = self._stack_at(s)
            idents = {layer.ident for layer in stack.layers if layer.stateful}
            carry = {ident: v for ident, v in carry.items() if ident in idents}
            piece, carry = _run_stack(stack, self._keys, s, e - s, carry)
            pieces.append(piece)
        return pieces, carry

    def _carry_at(self, k: int) -> Carry:
        """Chain states at the start of block ``k``, running earlier blocks if needed."""
        if not any(s.stateful for _, s in self._timeline):
            return {}
        j = max(i for i in self._carries if i <= k)
        while j < k:
            _, self._carries[j + 1] = self._run_range(
                j * self._b, (j + 1) * self._b, self._carries[j]
            )
            j += 1
        return self._carries[k]

    def _block(self, k: int) -> _Block:
        a = k * self._b
        pieces, end = self._run_range(a, a + self._b, self._carry_at(k))
        self._carries[k + 1] = end
        decisions: list[Decision] = []
        memo: dict[tuple[Any, ...], Decision] = {}
        for p in pieces:
            kinds = [layer.kind for layer in p.stack.layers]
            _, copies, de, dms, reo = p.final()
            rows = zip(
                p.first[0].tolist(),
                copies[0].tolist(),
                de[0].tolist(),
                dms[0].tolist(),
                reo[0].tolist(),
                map(tuple, p.states[0].tolist()),
                strict=True,
            )
            for row in rows:
                d = memo.get(row)
                if d is None:
                    first, c, e, ms, r, codes = row
                    model = kinds[first] if first >= 0 else ""
                    d = memo[row] = _make_decision(model, c, e, ms, r, _state_string(kinds, codes))
                decisions.append(d)
            memo.clear()  # kinds differ between pieces
        blk = _Block(a, pieces, decisions, any(p.stack.timed for p in pieces))
        while len(self._blocks) >= self._cache_blocks:
            del self._blocks[next(iter(self._blocks))]
        self._blocks[k] = blk
        return blk

    def _require_times(self, pieces: Sequence[_Piece]) -> None:
        for p in pieces:
            for i in p.stack.timed:
                o = p.stack.specs[i]
                assert isinstance(o, Outage)
                raise LinkModelError(
                    self.link,
                    f"stack[{i}] outage is given in seconds (start_s = {o.start_s}, "
                    f"end_s = {o.end_s}); the decision needs the packet time time_s",
                )

    def _packet_draws(self, p: _Piece, seq: int) -> tuple[list[int], list[int], list[float]]:
        """Extra copies and delays of packet ``seq`` of every epoch of a piece."""
        epochs = np.arange(p.start, p.start + p.n, dtype=np.int64)
        dup = np.zeros(p.n, dtype=np.int64)
        de = np.zeros(p.n, dtype=np.int64)
        dms = np.zeros(p.n, dtype=np.float64)
        for i, layer in enumerate(p.stack.layers):
            if isinstance(layer, _Duplicate):
                dup += layer.draw(self._keys, epochs, seq)[0]
            elif isinstance(layer, _Delay):
                u = layer.fresh(self._keys, epochs, seq)
                if layer.stateful:
                    c = layer.d.correlation
                    u = (1.0 - c) * u + c * p.chain_prev[i]
                e, ms = layer.values(u)
                de += e[0]
                dms += ms[0]
        return dup.tolist(), de.tolist(), dms.tolist()

    def _decide_slow(self, blk: _Block, epoch: int, seq: int, time_s: float | None) -> Decision:
        """Packets with ``seq > 0`` or under a realtime window: one packet, from the block's chains."""
        which = next(i for i in reversed(range(len(blk.pieces))) if blk.pieces[i].start <= epoch)
        p = blk.pieces[which]
        j = epoch - p.start
        layers = p.stack.layers
        first = int(p.first[0, j])
        codes = p.states[0, j].tolist()
        dup, de, dms = int(p.dup[0, j]), int(p.delay_epochs[0, j]), float(p.delay_ms[0, j])
        if seq != 0:
            if seq < 0 or seq >= _KEY_LIMIT:
                raise LinkModelError(self.link, f"seq = {seq}; expected an integer in [0, 2**63)")
            extra = blk.by_seq.get((which, seq))
            if extra is None:
                extra = blk.by_seq[(which, seq)] = self._packet_draws(p, seq)
            dup, de, dms = extra[0][j], extra[1][j], extra[2][j]
        if p.stack.timed:
            if time_s is None:
                self._require_times([p])
            else:
                for i in p.stack.timed:
                    layer = layers[i]
                    assert isinstance(layer, _Outage)
                    down = layer.start_s <= time_s < layer.end_s
                    codes[i] = int(down)
                    if down and (first < 0 or i < first):
                        first = i
        kinds = [layer.kind for layer in layers]
        reordered = bool(p.reorder[0, j])
        if first >= 0:
            return _make_decision(kinds[first], 0, 0, 0.0, False, _state_string(kinds, codes))
        if reordered:
            de, dms = 0, 0.0
        return _make_decision("", 1 + dup, de, dms, reordered, _state_string(kinds, codes))


def _trim(pieces: list[_Piece], start: int) -> list[_Piece]:
    """Drop epochs before ``start`` from pieces that begin at a block start."""
    out = []
    for p in pieces:
        end = p.start + p.n
        if end <= start:
            continue
        if p.start < start:
            s = start - p.start
            p = _Piece(
                start,
                p.stack,
                p.first[:, s:],
                p.dup[:, s:],
                p.delay_epochs[:, s:],
                p.delay_ms[:, s:],
                p.reorder[:, s:],
                p.states[:, s:],
                {i: v[:, s:] for i, v in p.chain_prev.items()},
            )
        out.append(p)
    return out


def _schedule_of(pieces: Sequence[_Piece], start: int, n: int) -> Schedule:
    width = max((len(p.stack.layers) for p in pieces), default=0)
    cols: dict[str, list[npt.NDArray[Any]]] = {
        k: [] for k in ("delivered", "copies", "de", "dms", "reo", "drop", "codes", "kinds")
    }
    for p in pieces:
        delivered, copies, de, dms, reo = p.final()
        kinds = np.array([_KIND_CODE[layer.kind] for layer in p.stack.layers], dtype=np.int8)
        pad = width - kinds.shape[0]
        kind_of_layer = np.concatenate([kinds, [-1]]).astype(np.int8)  # index -1 → -1
        cols["delivered"].append(delivered[0])
        cols["copies"].append(copies[0])
        cols["de"].append(de[0])
        cols["dms"].append(dms[0])
        cols["reo"].append(reo[0])
        cols["drop"].append(kind_of_layer[p.first[0]])
        cols["codes"].append(np.pad(p.states[0], ((0, 0), (0, pad)), constant_values=-1))
        kinds_row = np.concatenate([kinds, np.full(pad, -1, np.int8)])
        cols["kinds"].append(np.broadcast_to(kinds_row, (p.n, width)))

    def cat(name: str, dtype: type, *shape: int) -> npt.NDArray[Any]:
        parts = cols[name]
        return np.concatenate(parts).astype(dtype) if parts else np.zeros(shape, dtype)

    return Schedule(
        epochs=np.arange(start, start + n, dtype=np.int64),
        delivered=cat("delivered", np.bool_, 0),
        copies=cat("copies", np.int8, 0),
        delay_epochs=cat("de", np.int64, 0),
        delay_ms=cat("dms", np.float64, 0),
        reordered=cat("reo", np.bool_, 0),
        drop_model=cat("drop", np.int8, 0),
        state_codes=cat("codes", np.int8, 0, width),
        layer_kinds=cat("kinds", np.int8, 0, width),
    )


# ----------------------------------------------------------------------------- batch forms


def schedule(
    specs: Sequence[LinkModelSpec],
    seed: int,
    src: int,
    dst: int,
    n_epochs: int,
    times_s: npt.ArrayLike | None = None,
) -> Schedule:
    """Decisions of link ``src → dst`` for epochs ``0 .. n_epochs - 1``, vectorised.

    Equal, decision by decision, to ``LinkModel(specs, seed, src, dst).decide(k)``.
    """
    return LinkModel(specs, seed, src, dst).schedule(n_epochs, times_s=times_s)


def delivery_matrix(
    specs_per_link: Sequence[Sequence[LinkModelSpec]],
    seed: int,
    links: npt.ArrayLike,
    n_epochs: int,
    times_s: npt.ArrayLike | None = None,
) -> LinkMatrix:
    """Decisions of many links at once, for the in-process simulator and sweeps.

    Links with equal stacks are computed together: stateless layers over
    ``(links, epochs)`` in one go, Markov chains vectorised across links with a
    loop over epochs. Column ``l`` equals ``schedule(specs_per_link[l], seed,
    *links[l], n_epochs)``.

    Parameters
    ----------
    specs_per_link : sequence of L stacks
    seed : int
    links : (L, 2) int array
        ``(src, dst)`` of each directed link.
    n_epochs : int
    times_s : (n_epochs,) array [s], optional
        Packet times, needed when a realtime outage window is in a stack.

    Returns
    -------
    LinkMatrix
        ``delivered``, ``copies``, ``delay_epochs``, ``delay_ms``, ``reordered``, each ``(n_epochs, L)``.
    """
    pairs = np.asarray(links, dtype=np.int64)
    if pairs.ndim != 2 or pairs.shape[1] != 2:
        raise LinkModelError("matrix", f"links has shape {pairs.shape}; expected (L, 2)")
    if len(specs_per_link) != pairs.shape[0]:
        raise LinkModelError(
            "matrix", f"{len(specs_per_link)} stacks for {pairs.shape[0]} links; expected one each"
        )
    times = None if times_s is None else np.asarray(times_s, dtype=np.float64)
    if times is not None and times.shape != (n_epochs,):
        raise LinkModelError("matrix", f"times_s has shape {times.shape}; expected ({n_epochs},)")
    n_links = pairs.shape[0]
    delivered = np.zeros((n_links, n_epochs), np.bool_)
    copies = np.zeros((n_links, n_epochs), np.int8)
    delay_epochs = np.zeros((n_links, n_epochs), np.int64)
    delay_ms = np.zeros((n_links, n_epochs), np.float64)
    reordered = np.zeros((n_links, n_epochs), np.bool_)
    groups: dict[tuple[LinkModelSpec, ...], list[int]] = {}
    for i, specs in enumerate(specs_per_link):
        groups.setdefault(tuple(specs), []).append(i)
    for stack_specs, members in groups.items():
        idx = np.asarray(members)
        name = f"{pairs[idx[0], 0]}→{pairs[idx[0], 1]}"
        for j in (0, 1):
            for v in pairs[idx, j].tolist():
                _check_key(name, "src" if j == 0 else "dst", v)
        _check_key(name, "seed", seed)
        stack = _build_stack(stack_specs, name)
        keys = _Keys(seed, pairs[idx, 0:1], pairs[idx, 1:2])
        piece, _ = _run_stack(stack, keys, 0, n_epochs, {})
        if times is not None:
            piece.apply_times(times)
        elif stack.timed:
            raise LinkModelError(name, "a stack has an outage in seconds; pass times_s")
        d, c, de, dms, r = piece.final()
        delivered[idx], copies[idx], delay_epochs[idx], delay_ms[idx], reordered[idx] = (
            d,
            c,
            de,
            dms,
            r,
        )
    return LinkMatrix(
        np.ascontiguousarray(delivered.T),
        np.ascontiguousarray(copies.T),
        np.ascontiguousarray(delay_epochs.T),
        np.ascontiguousarray(delay_ms.T),
        np.ascontiguousarray(reordered.T),
    )


# ----------------------------------------------------------------------------- closed forms


def _loss_chain(spec: LinkModelSpec) -> tuple[Floats, Floats] | None:
    """``(T, loss)`` of a loss layer as a hidden Markov chain started in state 0; None if none."""
    if isinstance(spec, Up | Delay | Duplicate | Reorder):
        return np.ones((1, 1)), np.zeros(1)
    if isinstance(spec, Down):
        return np.ones((1, 1)), np.ones(1)
    if isinstance(spec, Bernoulli) and spec.correlation == 0.0:
        return np.ones((1, 1)), np.array([spec.p_loss])
    if isinstance(spec, GilbertElliott):
        p, r = spec.p, spec.r
        return np.array([[1 - p, p], [r, 1 - r]]), np.array([spec.one_minus_k, spec.one_minus_h])
    if isinstance(spec, Markov4):
        s = spec
        t = np.array(
            [
                [1 - s.p13 - s.p14, 0.0, s.p13, s.p14],
                [0.0, 1 - s.p23, s.p23, 0.0],
                [s.p31, s.p32, 1 - s.p31 - s.p32, 0.0],
                [1.0, 0.0, 0.0, 0.0],
            ]
        )
        return t, np.array([0.0, 0.0, 1.0, 1.0])
    return None


def _cesaro(t: Floats) -> Floats:
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


def stationary_distribution(spec: GilbertElliott | Markov4) -> Floats:
    """Long-run state occupancy of a Gilbert–Elliott ``[good, bad]`` or markov4 ``[π1..π4]`` chain.

    Gilbert–Elliott: ``π_bad = p / (p + r)``. Four-state (Salsano et al. GI
    model, Linux ``loss_4state``): ``π1 = p31 p23 / D``, ``π2 = p13 p32 / D``,
    ``π3 = p13 p23 / D``, ``π4 = p14 p31 p23 / D``, ``D`` their sum. Computed as
    the Cesàro limit from the initial state, so degenerate parameters give the
    occupancy the chain really has.
    """
    chain = _loss_chain(spec)
    assert chain is not None
    return np.array(_cesaro(chain[0])[0], dtype=np.float64)


def _ar1_uniform_cdf(c: float, x: float) -> float:
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


def _layer_loss_rate(spec: LinkModelSpec) -> float:
    if isinstance(spec, Bernoulli) and spec.correlation > 0.0:
        return _ar1_uniform_cdf(spec.correlation, spec.p_loss)
    if isinstance(spec, Outage):
        if spec.start_s is not None or spec.end_s is not None:
            return 1.0 if spec.end_s is None else 0.0
        if spec.end is None:
            return 1.0
        return (spec.end - spec.start) / spec.every if spec.every is not None else 0.0
    chain = _loss_chain(spec)
    assert chain is not None
    t, loss = chain
    return float(_cesaro(t)[0] @ loss)


def _as_stack(specs: LinkModelSpec | Sequence[LinkModelSpec]) -> list[LinkModelSpec]:
    if isinstance(specs, Sequence):
        return list(specs)
    return [specs]


def expected_loss_rate(specs: LinkModelSpec | Sequence[LinkModelSpec]) -> float:
    """Long-run fraction of epochs whose packets are dropped by a stack (or one spec).

    Layers drop independently, so the stack loses ``1 - Π (1 - ρ_l)``. Per layer
    ``ρ``: bernoulli ``p_loss`` (with correlation, the stationary probability that
    tc's correlated uniform is below ``p_loss``, computed numerically);
    Gilbert–Elliott ``π_bad (1-h) + π_good (1-k)``; markov4 ``π3 + π4``; a
    repeating outage ``(end - start) / every``, a one-off window 0 (1 if it never
    ends); delay, duplicate, reorder 0.
    """
    keep = 1.0
    for spec in _as_stack(specs):
        keep *= 1.0 - _layer_loss_rate(spec)
    return 1.0 - keep


def expected_burst_length(specs: LinkModelSpec | Sequence[LinkModelSpec]) -> float:
    """Long-run mean length of runs of consecutive dropped epochs.

    With the stack as a hidden Markov chain (transition ``T``, loss probability
    ``ℓ`` per state, occupancy ``π``): bursts start at rate
    ``Σ_s π_s (1 - ℓ_s) (T ℓ)_s`` and losses occur at rate ``π · ℓ``; the mean
    burst is their ratio (Bernoulli: ``1 / (1 - p)``; Gilbert with ``1-h = 1``,
    ``1-k = 0``: ``1 / r``). ``inf`` when every epoch is lost, ``nan`` when none
    is. Defined for stacks of up, down, bernoulli without correlation,
    gilbert_elliott, markov4, delay, duplicate and reorder.
    """
    t = np.ones((1, 1))
    loss_keep = np.ones(1)
    for i, spec in enumerate(_as_stack(specs)):
        chain = _loss_chain(spec)
        if chain is None:
            raise LinkModelError(
                "closed form", f"stack[{i}] {spec.model} has no closed-form burst length"
            )
        t = np.asarray(np.kron(t, chain[0]), dtype=np.float64)
        loss_keep = np.asarray(np.kron(loss_keep, 1.0 - chain[1]), dtype=np.float64)
    loss = 1.0 - loss_keep
    occupancy = _cesaro(t)[0]
    rate = float(occupancy @ loss)
    starts = float(occupancy @ (loss_keep * (t @ loss)))
    if rate <= 0.0:
        return math.nan
    return math.inf if starts <= 0.0 else rate / starts


class DelayMoments(NamedTuple):
    """Mean and standard deviation of a delay layer's delays, lockstep and realtime."""

    mean_epochs: float
    std_epochs: float
    mean_ms: float
    std_ms: float


def delay_moments(spec: Delay, n_points: int = 1 << 20) -> DelayMoments:
    """Moments of the delays of one uncorrelated delay layer (clipping at 0 and rounding included).

    Lockstep uniform jitter is exact (``2j + 1`` equally likely values: variance
    ``j (j + 1) / 3`` when ``epochs >= j``); the others integrate the delay over
    the uniform draw ``u`` by the midpoint rule on ``n_points`` points. Normal
    jitter has standard deviation ``jitter`` (tables clip at ±4σ); the pareto and
    paretonormal tables have mean and spread of their own, which this measures.
    """
    if spec.correlation > 0.0:
        raise LinkModelError(
            "closed form",
            f"delay correlation = {spec.correlation}; moments are given for correlation 0",
        )
    layer = _Delay(spec, 0)
    u = (np.arange(n_points, dtype=np.float64) + 0.5) / n_points
    de, dms = layer.values(u)
    if spec.distribution == "uniform" and spec.jitter_epochs > 0:
        j = spec.jitter_epochs
        de = np.maximum(spec.epochs + np.arange(-j, j + 1), 0)
    return DelayMoments(float(de.mean()), float(de.std()), float(dms.mean()), float(dms.std()))


__all__ = [
    "MODEL_NAMES",
    "Decision",
    "DelayMoments",
    "LinkMatrix",
    "LinkModel",
    "LinkModelError",
    "Schedule",
    "delay_moments",
    "delivery_matrix",
    "expected_burst_length",
    "expected_loss_rate",
    "schedule",
    "stationary_distribution",
]
