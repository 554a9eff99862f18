"""A stack of layers run over epochs, and the records of what it decides (docs/model.md §4).

``run_stack`` runs a stack's layers over consecutive epochs for one or more
links; ``Outcome``, ``Schedule`` and ``LinkMatrix`` are what netem answers with.
Nothing here knows a model: each layer comes from ``netem.links.linkmodels`` by its tag.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from formation.errors import LinkModelError, PluginFailure
from formation.linkmodels import LinkModelSpec
from netem.links.layer import (
    MODEL_NAMES,
    STATE_NAMES,
    Bools,
    Codes,
    Floats,
    Ints,
    Keys,
    Layer,
    LayerOutput,
    model_index,
)
from netem.links.linkmodels import layer_of

Carry = dict[tuple[str, int], npt.NDArray[Any]]  # chain state per layer ident (kind, occurrence)

KEY_LIMIT = 2**63  # keys (seed, link ends, epochs, seq) are integers in [0, 2**63)


class Outcome(NamedTuple):
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

    def decision(self, i: int) -> Outcome:
        """The decision at index ``i`` (epoch ``epochs[i]``), as ``LinkModel.decide`` gives it."""
        kinds = [k for k in self.layer_kinds[i].tolist() if k >= 0]
        codes = self.state_codes[i].tolist()[: len(kinds)]
        dm = int(self.drop_model[i])
        return make_decision(
            MODEL_NAMES[dm] if dm >= 0 else "",
            int(self.copies[i]),
            int(self.delay_epochs[i]),
            float(self.delay_ms[i]),
            bool(self.reordered[i]),
            state_string([MODEL_NAMES[k] for k in kinds], codes),
        )

    def state_of(self, model: str, occurrence: int = 0) -> Codes:
        """State codes ``(n,)`` of the ``occurrence``-th layer of kind ``model``; -1 where absent."""
        kind = model_index(model)
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


# ----------------------------------------------------------------------------- stacks


@dataclass(frozen=True)
class Stack:
    """The specs of a link and their layers, in stack order."""

    specs: tuple[LinkModelSpec, ...]
    layers: tuple[Layer[Any], ...]

    @property
    def stateful(self) -> bool:
        return any(layer.stateful for layer in self.layers)

    @cached_property
    def timed(self) -> tuple[int, ...]:
        """Indices of the layers that decide by the packet's time (asked for every packet)."""
        return tuple(i for i, layer in enumerate(self.layers) if layer.timed)

    @cached_property
    def ranged(self) -> tuple[int, ...]:
        """Indices of the layers that decide by the link's length (asked for every packet)."""
        return tuple(i for i, layer in enumerate(self.layers) if layer.ranged)


def build_stack(specs: Sequence[LinkModelSpec], link: str) -> Stack:
    """The layers of ``specs``, each keyed by its kind and occurrence; errors name ``link``."""
    layers: list[Layer[Any]] = []
    seen: dict[str, int] = {}
    for i, spec in enumerate(specs):
        cls = layer_of(spec)
        if cls is None:
            raise LinkModelError(link, f"stack[{i}] = {spec!r}; expected a LinkModelSpec")
        occ = seen.get(spec.model, 0)
        seen[spec.model] = occ + 1
        layer = cls(spec, occ)
        problem = layer.problem()
        if problem is not None:
            raise LinkModelError(link, f"stack[{i}] {problem}")
        layers.append(layer)
    return Stack(tuple(specs), tuple(layers))


def probe_stack(specs: Sequence[LinkModelSpec], link: str) -> None:
    """Build ``specs`` and run them over a few epochs of two links (``1 → 2``, ``2 → 1``), as
    at load time: a plug-in's mistake is found before any process starts."""
    stack = build_stack(specs, link)
    keys = Keys(0, np.array([[1], [2]], np.int64), np.array([[2], [1]], np.int64))
    run_stack(stack, keys, 0, 8, {})


# ----------------------------------------------------------------------------- one run of a stack


@dataclass
class Piece:
    """A stack run over epochs ``start .. start + n - 1`` for ``L`` links (raw, before drops)."""

    start: int
    stack: Stack
    first: npt.NDArray[np.int16]  # (L, n) first dropping layer, -1 none
    dup: npt.NDArray[np.int8]  # (L, n) extra copies
    delay_epochs: Ints  # (L, n) summed over delay layers
    delay_ms: Floats
    reorder: Bools
    states: Codes  # (L, n, len(layers))
    chain_prev: dict[int, Floats] = field(default_factory=dict)
    reach_m: dict[int, Floats] = field(default_factory=dict)  # distance layer → (L, n) [m]

    @property
    def n(self) -> int:
        return int(self.first.shape[1])

    def drop(self, i: int, lost: Bools) -> None:
        """Layer ``i`` drops where ``lost`` ``(L, n)``; a timed layer's state then says down."""
        self.first = _first_drop(self.first, i, lost)
        if self.stack.layers[i].timed:
            self.states[:, :, i] = lost

    def apply_times(self, time_s: Floats) -> None:
        """Drop by the realtime outage windows at packet times ``time_s`` ``(n,)`` [s]."""
        for i in self.stack.timed:
            self.drop(i, np.broadcast_to(self.stack.layers[i].drops_at(time_s), self.first.shape))

    def apply_distances(self, distance_m: Floats) -> None:
        """Drop by the distance layers at link lengths ``distance_m`` ``(L, n)`` [m]."""
        for i in self.stack.ranged:
            self.drop(i, ~self.stack.layers[i].keeps(self.reach_m[i], distance_m))

    def with_verdicts(self, verdicts: Sequence[tuple[int, bool]]) -> Piece:
        """A copy in which each layer ``i`` of ``verdicts`` drops at every epoch (``True``) or at
        none: one packet's realtime windows and distance layers, applied to the whole piece so
        its decisions can be coded once and served per packet."""
        p = replace(self, first=self.first.copy(), states=self.states.copy())
        for i, lost in verdicts:
            p.drop(i, np.full(p.first.shape, lost))
        return p

    def for_packet(self, keys: Keys, seq: int) -> Piece:
        """The piece for packet ``seq`` of each epoch: the per-packet draws (duplicates, delays) of
        ``Layer.packet``, the per-epoch verdicts and states shared with packet 0."""
        epochs = np.arange(self.start, self.start + self.n, dtype=np.int64)
        dup = np.zeros_like(self.dup)
        delay_epochs = np.zeros_like(self.delay_epochs)
        delay_ms = np.zeros_like(self.delay_ms)
        for i, layer in enumerate(self.stack.layers):
            out = layer.packet(keys, epochs, seq, self.chain_prev.get(i))
            if out is not None:
                _add_draws(out, dup, delay_epochs, delay_ms)
        return replace(self, dup=dup, delay_epochs=delay_epochs, delay_ms=delay_ms)

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


def run_stack(stack: Stack, keys: Keys, start: int, n: int, carry: Carry) -> tuple[Piece, Carry]:
    """Run ``stack`` over epochs ``start .. start + n - 1`` from chain states ``carry``.

    Returns the raw piece (before drops are applied) and the chain states after it.
    """
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
    reach_m: dict[int, Floats] = {}
    after: Carry = {}
    for i, layer in enumerate(stack.layers):
        out, end = _run_layer(layer, keys, epochs, carry.get(layer.ident))
        if end is not None:
            after[layer.ident] = end
        if out.drop is not None:
            drops.append((i, out.drop))
        if out.state is not None:
            states[:, :, i] = out.state
        _add_draws(out, dup, delay_epochs, delay_ms)
        if out.reorder is not None:
            reorder |= out.reorder
        if out.chain_prev is not None:
            chain_prev[i] = out.chain_prev
        if layer.ranged and out.reach_m is not None:
            reach_m[i] = out.reach_m
    for i, drop in drops:
        first = _first_drop(first, i, drop)
    piece = Piece(
        start, stack, first, dup, delay_epochs, delay_ms, reorder, states, chain_prev, reach_m
    )
    return piece, after


def _run_layer(
    layer: Layer[Any], keys: Keys, epochs: Ints, carry: npt.NDArray[Any] | None
) -> tuple[LayerOutput, Any]:
    """``layer.run`` with its answer checked: a plug-in's failure names it, the links and the epoch."""
    try:
        out, end = layer.run(keys, epochs, carry)
    except Exception as exc:  # a user's layer: any exception ends the run with its name
        at = _first_failing(layer, keys, epochs, carry)
        raise _failure(layer, keys, at, f"raised {type(exc).__name__}: {exc}") from exc
    if not isinstance(out, LayerOutput):
        raise _failure(layer, keys, epochs, f"returned {type(out).__name__}, not a LayerOutput")
    shape = (keys.n_links, epochs.shape[0])
    for name in ("drop", "state", "delay_epochs", "delay_ms", "dup", "reorder"):
        value = getattr(out, name)
        if value is not None and np.shape(value) != shape:
            problem = f"LayerOutput.{name} has the shape {np.shape(value)}; expected {shape}"
            raise _failure(layer, keys, epochs, problem)
    if out.delay_ms is not None and not np.isfinite(out.delay_ms).all():
        first = int(np.argmin(np.isfinite(out.delay_ms).all(axis=0)))  # the epoch it belongs to
        raise _failure(layer, keys, epochs[first:], "LayerOutput.delay_ms is not finite")
    return out, end


def _first_failing(
    layer: Layer[Any], keys: Keys, epochs: Ints, carry: npt.NDArray[Any] | None
) -> Ints:
    """The epochs from the first one whose run alone raises (a block's failure names its epoch)."""
    for i in range(epochs.shape[0]):
        try:
            _, carry = layer.run(keys, epochs[i : i + 1], carry)
        except Exception:
            return epochs[i:]
    return epochs


def _failure(layer: Layer[Any], keys: Keys, epochs: Ints, problem: str) -> PluginFailure:
    ends = [
        f"{a}->{b}" for a, b in zip(keys.src[:, 0].tolist(), keys.dst[:, 0].tolist(), strict=True)
    ]
    where = (
        ("link " if len(ends) == 1 else "links ")
        + ", ".join(ends[:6])
        + (", …" if len(ends) > 6 else "")
    )
    first = int(epochs[0]) if epochs.size else 0
    return PluginFailure("link_model", layer.kind, where, first, problem)


def _first_drop(first: npt.NDArray[np.int16], i: int, lost: Bools) -> npt.NDArray[np.int16]:
    """``first`` (the first dropping layer, -1 none) after layer ``i`` drops where ``lost``: a
    packet is dropped when any layer drops it, and the first in stack order names the drop."""
    return np.where(lost & ((first < 0) | (first > i)), np.int16(i), first).astype(np.int16)


def _add_draws(
    out: LayerOutput, dup: npt.NDArray[np.int8], delay_epochs: Ints, delay_ms: Floats
) -> None:
    """Add a layer's duplicates and delays to the stack's, in place: delays of layers add up."""
    if out.delay_epochs is not None and out.delay_ms is not None:
        delay_epochs += out.delay_epochs
        delay_ms += out.delay_ms
    if out.dup is not None:
        dup += out.dup.astype(np.int8)


def state_string(kinds: Sequence[str], codes: Sequence[int]) -> str:
    """``Outcome.state``: the named states of the layers ``kinds`` with codes ``codes``, by ","."""
    names = []
    for kind, code in zip(kinds, codes, strict=False):
        name = STATE_NAMES[kind][code] if code >= 0 else ""
        if name:
            names.append(name)
    return ",".join(names)


def make_decision(
    model: str, copies: int, delay_epochs: int, delay_ms: float, reordered: bool, state: str
) -> Outcome:
    """The decision with its verdict; ``model`` is the dropping model, "" when delivered."""
    if model:
        return Outcome(False, 0, 0.0, 0, "drop", model, state, False)
    if copies > 1:
        verdict = "duplicate"
    elif delay_epochs > 0 or delay_ms > 0.0:
        verdict = "delayed"
    else:
        verdict = "pass"
    return Outcome(True, delay_epochs, delay_ms, copies, verdict, "", state, reordered)


def check_key(link: str, name: str, value: int) -> None:
    """Raise unless ``value`` can be a key (an integer in ``[0, 2**63)``)."""
    if not 0 <= value < KEY_LIMIT:
        raise LinkModelError(link, f"{name} = {value}; expected an integer in [0, 2**63)")


def trim_pieces(pieces: list[Piece], start: int) -> list[Piece]:
    """Drop epochs before ``start`` from pieces that begin at a block start."""
    out = []
    for p in pieces:
        end = p.start + p.n
        if end <= start:
            continue
        if p.start < start:
            s = start - p.start
            p = Piece(
                start,
                p.stack,
                p.first[:, s:],
                p.dup[:, s:],
                p.delay_epochs[:, s:],
                p.delay_ms[:, s:],
                p.reorder[:, s:],
                p.states[:, s:],
                {i: v[:, s:] for i, v in p.chain_prev.items()},
                {i: v[:, s:] for i, v in p.reach_m.items()},
            )
        out.append(p)
    return out


def schedule_of(pieces: Sequence[Piece], start: int, n: int) -> Schedule:
    """The pieces' decisions of epochs ``start .. start + n - 1`` as one ``Schedule``."""
    width = max((len(p.stack.layers) for p in pieces), default=0)
    cols: dict[str, list[npt.NDArray[Any]]] = {
        k: [] for k in ("delivered", "copies", "de", "dms", "reo", "drop", "codes", "kinds")
    }
    for p in pieces:
        delivered, copies, de, dms, reo = p.final()
        kinds = np.array([model_index(layer.kind) for layer in p.stack.layers], dtype=np.int8)
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


__all__ = [
    "KEY_LIMIT",
    "Carry",
    "LinkMatrix",
    "Outcome",
    "Piece",
    "Schedule",
    "Stack",
    "build_stack",
    "check_key",
    "make_decision",
    "probe_stack",
    "run_stack",
    "schedule_of",
    "state_string",
    "trim_pieces",
]
