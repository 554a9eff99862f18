"""What netem does to each packet of a directed link: pass, drop, delay, duplicate, reorder.

The functional core of netem (docs/architecture.md "Time"; docs/model.md §4, §8): numpy in,
numpy out, no clocks, no Zenoh, no global random state. Every draw comes from
``formation.keyed_random`` keyed by ``(seed, stream, src, dst, kind, occurrence,
epoch[, seq], slot)``, so a decision depends only on its key: any process, asking
epochs in any order, gets the same answer, and the in-process simulator
(``delivery_matrix``) gets the same numbers as the netem process (``LinkModel``).

Semantics (tc netem's where it has them, see ``man tc-netem`` and Linux
``net/sched/sch_netem.c``):

* **A stack** of specs is applied in order. Loss layers (up, down, bernoulli,
  gilbert_elliott, markov4, outage) each decide independently; a packet is
  dropped when any of them drops it, and ``Outcome.model`` names the first one
  in stack order that did. Every layer's chain runs whether or not another layer
  dropped the packet, so adding an outage on top of a Bernoulli loss leaves the
  Bernoulli decisions outside the window unchanged (draws are keyed by the
  layer's kind and its occurrence among layers of that kind, not by position).
* **Loss is per epoch.** A link is healthy or not at an epoch (docs/model.md §4): all
  packets of one epoch on one link share the loss verdict and the Markov state;
  chains step once per epoch. **Delay and duplication are per packet**, keyed by
  ``(epoch, seq)`` where ``seq`` is the index of the packet among the link's
  packets of that epoch (0 for the first; the lockstep protocol sends one), not
  the publisher's wire sequence number, which the simulator does not have.
* **Each model's own semantics** (Gilbert–Elliott and four-state chains,
  correlated Bernoulli, outage windows in epochs or seconds, delay
  distributions, duplicate, reorder) are in the docstring of its module,
  ``netem/links/linkmodels/<tag>.py``, beside its layer and closed forms.
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
link; ``bench/bench_netem_models.py`` measures it. A packet with ``seq > 0``, under a
realtime window or dropped by a distance layer is decided by the same pieces: the
block's piece for that packet (``Piece.for_packet``) with that packet's verdicts
applied to every epoch (``Piece.with_verdicts``), coded once and cached per block.

Layout: the specs are in ``formation.linkmodels``; each model's layer and closed
forms in ``netem.links.linkmodels.<tag>`` (the registry, ``netem.links.linkmodels``, says how
to add one); a stack's run and the records (``Outcome``, ``Schedule``,
``LinkMatrix``) in ``netem.links.layer_stack``; the closed forms of a stack in
``netem.links.closed_forms``. This module holds ``LinkModel`` and the batch forms and
re-exports the rest.

References: Linux ``net/sched/sch_netem.c`` (``loss_4state``,
``loss_gilb_ell``, ``get_crandom``, ``tabledist``, ``netem_enqueue``); iproute2
``tc/q_netem.c`` (``1-h`` is sent to the kernel as ``h``) and
``netem/{normal,pareto,paretonormal}.c``; S. Salsano, F. Ludovici, A. Ordine,
"Definition of a general and intuitive loss model for packet networks and its
implementation in the Netem module in the Linux kernel" (NetemCLG).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from formation.errors import LinkModelError, PluginFailure
from formation.linkmodels import LinkModelSpec
from netem.links.closed_forms import (
    DelayMoments,
    delay_moments,
    expected_burst_length,
    expected_delivery_at,
    expected_loss_rate,
    stationary_distribution,
)
from netem.links.decision_table import LazyTable, coded_table
from netem.links.layer import MODEL_NAMES, Floats, Keys
from netem.links.layer_stack import (
    KEY_LIMIT,
    Carry,
    LinkMatrix,
    Outcome,
    Piece,
    Schedule,
    Stack,
    build_stack,
    check_key,
    run_stack,
    schedule_of,
    trim_pieces,
)
from netem.links.matrix import delivery_matrix, link_lengths

# ----------------------------------------------------------------------------- one link

Verdicts = tuple[tuple[int, bool], ...]  # (timed or distance layer, drops) of one packet


@dataclass
class _Block:
    """Decisions of epochs ``start .. start + block - 1`` (``seq = 0``, no realtime windows)."""

    start: int
    pieces: list[Piece]
    code_list: list[int]  # epoch start + j is decided by table[code_list[j]]
    timed: bool
    codes: npt.NDArray[np.int64]  # code_list as an array
    ranged: bool  # a piece has a distance layer: table entries are before those layers
    table: list[Outcome]
    reach: Floats  # least reach [m] of the distance layers at each epoch, inf where none
    packets: dict[tuple[int, int], Piece] = field(default_factory=dict)  # (piece, seq) → its piece
    variants: dict[tuple[int, int, Verdicts], LazyTable] = field(
        default_factory=dict
    )  # (piece, seq, verdicts) → the piece's decisions under those verdicts
    # a layer that failed inside the block: epochs from failure.epoch on are not decided, and
    # asking one raises it then, so the run ends at the epoch the failure belongs to
    failure: PluginFailure | None = None

    def check(self, epoch: int) -> None:
        """Raise the block's failure if ``epoch`` is at or past it."""
        if self.failure is not None and epoch >= self.failure.epoch:
            raise self.failure


class LinkModel:
    """Decisions of one directed link ``src → dst`` (docs/model.md §4; docs/architecture.md "Time").

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
            check_key(self.link, name, value)
        if block_epochs < 1 or cache_blocks < 1:
            raise LinkModelError(
                self.link,
                f"block_epochs = {block_epochs}, cache_blocks = {cache_blocks}; expected >= 1",
            )
        self.seed, self.src, self.dst = seed, src, dst
        self._keys = Keys(seed, np.array([[src]], np.int64), np.array([[dst]], np.int64))
        self._b = block_epochs
        self._cache_blocks = cache_blocks
        self._timeline: list[tuple[int, Stack]] = [(0, build_stack(specs, self.link))]
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

    def replace(self, specs: Sequence[LinkModelSpec], from_epoch: int) -> None:
        """Use ``specs`` from ``from_epoch`` on; decisions before it stay what they were.

        Later changes already given are superseded. Stateful layers carry their
        state into a layer of the same kind and occurrence (module docstring).
        """
        check_key(self.link, "from_epoch", from_epoch)
        stack = build_stack(specs, self.link)
        kept = [(f, s) for f, s in self._timeline if f < from_epoch]  # the first starts at 0
        self._timeline = [*kept, (from_epoch, stack)]
        k = from_epoch // self._b
        self._blocks = {i: blk for i, blk in self._blocks.items() if i < k}
        self._carries = {i: c for i, c in self._carries.items() if i <= k}

    def decide(
        self, epoch: int, seq: int = 0, time_s: float | None = None, distance_m: float | None = None
    ) -> Outcome:
        """The decision for packet ``seq`` of ``epoch`` (realtime windows at ``time_s`` [s]; distance
        models at the link's length ``distance_m`` [m] at the epoch).

        The same answer for the same arguments, in any order of calls, in any process.
        """
        blk = self._blocks.get(epoch // self._b)
        if blk is None:
            if epoch < 0:
                raise LinkModelError(self.link, f"epoch = {epoch}; expected >= 0")
            blk = self._block(epoch // self._b)
        blk.check(epoch)
        if seq == 0 and not blk.timed and not blk.ranged:
            return blk.table[blk.code_list[epoch - blk.start]]
        return self._decide_packet(blk, epoch, seq, time_s, distance_m)

    def prepare(self, epoch: int) -> None:
        """Compute the block of decisions holding ``epoch`` now, if it is not cached, so the
        ``decide`` that needs it is fast (realtime: a block's first decision costs a whole
        block's, about 25 times an epoch of every link's)."""
        if epoch >= 0 and not self.prepared(epoch):
            self._block(epoch // self._b)

    def prepared(self, epoch: int) -> bool:
        """Is the block of decisions holding ``epoch`` computed?"""
        return epoch // self._b in self._blocks

    @property
    def ranged(self) -> bool:
        """Does a stack of the link decide by the link's length (``decide`` needs ``distance_m``)?"""
        return any(s.ranged for _, s in self._timeline)

    def coded(
        self, start: int, n_epochs: int, before_distance: bool = False
    ) -> tuple[npt.NDArray[np.int64], list[Outcome | None]]:
        """Epochs ``start .. start + n_epochs - 1`` as ``(codes, table)``: ``decide(k)`` is
        ``table[codes[k - start]]`` (packet 0), for vectorised use of many epochs.

        Under a realtime window or a distance model the verdict needs the packet's time
        or the link's length; such epochs get ``None`` in place of a decision, or with
        ``before_distance`` under a distance model the decision before its distance layers
        (a passing one stays as it is iff the length is within :meth:`reach`).
        """
        codes: list[npt.NDArray[np.int64]] = []
        table: list[Outcome | None] = []
        k, end = start, start + n_epochs
        while k < end:
            blk = self._blocks.get(k // self._b)
            if blk is None:
                if k < 0:
                    raise LinkModelError(self.link, f"epoch = {k}; expected >= 0")
                blk = self._block(k // self._b)
            stop = min(end, blk.start + self._b)
            part = blk.codes[k - blk.start : stop - blk.start] + len(table)
            unknown = blk.timed or (blk.ranged and not before_distance)
            table.extend([None] * len(blk.table) if unknown else blk.table)
            if len(part) < stop - k:  # past a failure: undecided, the model raises when asked
                part = np.concatenate([part, np.full(stop - k - len(part), len(table))])
                table.append(None)
            codes.append(part)
            k = stop
        return np.concatenate(codes), table

    def reach(self, start: int, n_epochs: int) -> Floats:
        """The least reach [m] of the distance layers at epochs ``start .. start + n_epochs - 1``,
        ``(n_epochs,)``: a length ``d`` keeps packet 0 of epoch ``k`` iff ``d <= reach[k - start]``
        (``Layer.keeps`` of every such layer); inf where none is in force."""
        out = np.full(n_epochs, np.inf)
        k, end = start, start + n_epochs
        while k < end:
            blk = self._blocks.get(k // self._b) or self._block(k // self._b)
            stop = min(end, blk.start + self._b)
            out[k - start : stop - start] = blk.reach[k - blk.start : stop - blk.start]
            k = stop
        return out

    def schedule(
        self,
        n_epochs: int,
        start: int = 0,
        times_s: npt.ArrayLike | None = None,
        distances_m: npt.ArrayLike | None = None,
    ) -> Schedule:
        """Decisions of epochs ``start .. start + n_epochs - 1`` (``seq = 0``) as arrays.

        ``times_s`` ``(n_epochs,)`` [s]: packet times, needed when a realtime outage is in force;
        ``distances_m`` ``(n_epochs,)`` [m]: the link's lengths, needed by a distance model.
        """
        if n_epochs < 0 or start < 0:
            raise LinkModelError(
                self.link, f"start = {start}, n_epochs = {n_epochs}; expected >= 0"
            )
        k = start // self._b
        carry = self._carry_at(k)
        pieces, _ = self._run_range(k * self._b, start + n_epochs, carry)
        pieces = trim_pieces(pieces, start)
        if times_s is not None:
            times = self._per_epoch(times_s, "times_s", n_epochs)
            for p in pieces:
                p.apply_times(times[p.start - start : p.start - start + p.n])
        else:
            self._require_times(pieces)
        if distances_m is not None:
            dist = self._per_epoch(distances_m, "distances_m", n_epochs)
            for p in pieces:
                p.apply_distances(dist[None, p.start - start : p.start - start + p.n])
        else:
            self._require_distance(pieces)
        return schedule_of(pieces, start, n_epochs)

    # internals ----------------------------------------------------------------------------------

    def _stack_at(self, epoch: int) -> Stack:
        stack = self._timeline[0][1]
        for f, s in self._timeline:
            if f <= epoch:
                stack = s
        return stack

    def _run_range(self, a: int, b: int, carry: Carry) -> tuple[list[Piece], Carry]:
        """Run epochs ``a .. b - 1`` from ``carry``, split where the stack changes."""
        cuts = sorted({a, b, *(f for f, _ in self._timeline if a < f < b)})
        pieces = []
        for s, e in itertools.pairwise(cuts):
            stack = self._stack_at(s)
            idents = {layer.ident for layer in stack.layers if layer.stateful}
            carry = {ident: v for ident, v in carry.items() if ident in idents}
            piece, carry = run_stack(stack, self._keys, s, e - s, carry)
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
        carry = self._carry_at(k)
        failure = None
        try:
            pieces, end = self._run_range(a, a + self._b, carry)
            self._carries[k + 1] = end
        except PluginFailure as exc:
            if exc.epoch <= a:
                raise
            failure = exc  # the epochs before it are decided as they would be without it
            pieces, _ = self._run_range(a, exc.epoch, carry)
        coded, table = coded_table(pieces)
        timed = any(p.stack.timed for p in pieces)
        ranged = any(p.stack.ranged for p in pieces)
        reach = np.full(self._b, np.inf)
        for p in pieces:
            for i in p.stack.ranged:
                part = reach[p.start - a : p.start - a + p.n]
                np.minimum(part, p.reach_m[i][0], out=part)
        blk = _Block(a, pieces, coded.tolist(), timed, coded, ranged, table, reach)
        blk.failure = failure
        while len(self._blocks) >= self._cache_blocks:
            del self._blocks[next(iter(self._blocks))]
        self._blocks[k] = blk
        return blk

    def _per_epoch(self, values: Any, name: str, n_epochs: int) -> Floats:
        """``values`` as floats ``(n_epochs,)``; an error naming ``name`` otherwise."""
        out = np.asarray(values, dtype=np.float64)
        if out.shape != (n_epochs,):
            raise LinkModelError(self.link, f"{name} has shape {out.shape}; expected ({n_epochs},)")
        return out

    def _require_times(self, pieces: Sequence[Piece]) -> None:
        for p in pieces:
            for i in p.stack.timed:
                raise LinkModelError(
                    self.link,
                    f"stack[{i}] {p.stack.layers[i].timing()}; the decision needs the packet time time_s",
                )

    def _require_distance(self, pieces: Sequence[Piece]) -> None:
        for p in pieces:
            for i in p.stack.ranged:
                raise LinkModelError(
                    self.link,
                    f"stack[{i}] {p.stack.layers[i].kind} decides by distance; "
                    "the decision needs the link's length distance_m",
                )

    def _verdicts(
        self, p: Piece, j: int, time_s: float | None, distance_m: float | None
    ) -> Verdicts:
        """Which timed and distance layers of piece ``p`` drop a packet of its epoch ``j`` sent at
        ``time_s`` [s] over a link of length ``distance_m`` [m]."""
        layers = p.stack.layers
        out: list[tuple[int, bool]] = []
        if p.stack.timed:
            if time_s is None:
                self._require_times([p])  # raises
            t = np.float64(time_s)
            out += [(i, bool(layers[i].drops_at(t))) for i in p.stack.timed]
        if p.stack.ranged:
            if distance_m is None:
                self._require_distance([p])  # raises
            d = np.float64(distance_m)
            out += [(i, not layers[i].keeps(p.reach_m[i][0, j], d)) for i in p.stack.ranged]
        return tuple(out)

    def _decide_packet(
        self, blk: _Block, epoch: int, seq: int, time_s: float | None, distance_m: float | None
    ) -> Outcome:
        """Packet ``seq`` of ``epoch`` under realtime windows or distance layers, or with
        ``seq > 0``: the stack's piece for that packet and its verdicts, coded once per block."""
        if not 0 <= seq < KEY_LIMIT:
            raise LinkModelError(self.link, f"seq = {seq}; expected an integer in [0, 2**63)")
        j = epoch - blk.start
        if seq == 0 and not blk.timed and distance_m is not None and distance_m <= blk.reach[j]:
            return blk.table[blk.code_list[j]]  # within the reach of every distance layer
        which = next(i for i in reversed(range(len(blk.pieces))) if blk.pieces[i].start <= epoch)
        p = blk.pieces[which]
        verdicts = self._verdicts(p, epoch - p.start, time_s, distance_m)
        if seq == 0 and not any(lost for _, lost in verdicts):
            return blk.table[blk.code_list[j]]
        coded = blk.variants.get((which, seq, verdicts))
        if coded is None:
            base = p
            if seq != 0:
                base = blk.packets.get((which, seq)) or p.for_packet(self._keys, seq)
                blk.packets[(which, seq)] = base
            coded = blk.variants[(which, seq, verdicts)] = LazyTable.of(
                base.with_verdicts(verdicts)
            )
        return coded.at(epoch - p.start)


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


__all__ = [
    "MODEL_NAMES",
    "DelayMoments",
    "LinkMatrix",
    "LinkModel",
    "Outcome",
    "Schedule",
    "delay_moments",
    "delivery_matrix",
    "expected_burst_length",
    "expected_delivery_at",
    "expected_loss_rate",
    "link_lengths",
    "schedule",
    "stationary_distribution",
]
