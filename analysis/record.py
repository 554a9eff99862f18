"""One run as arrays, from a recording or from the in-process simulator: the record of a run.

:class:`RunData` is what every summary reads (:func:`analysis.summarise`) and what
:func:`analysis.frames` turns into DataFrames: the recorder's (``recorder.read_run``, the
one decoder of a recording), the simulator's (``SimResult``, a subclass) and the launcher's
(``RunOutcome.record()``). What only some runs have is in typed sections: the
substitutions, netem's decisions, what a recording adds (:class:`Recorded`) and a realtime
run's deadline accounting.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

import analysis.membership as membership
from analysis.queues import Judged
from formation.rigidity import expected_rigidity_rank
from formation.scenario import Scenario

Array = npt.NDArray[np.float64]
Bools = npt.NDArray[np.bool_]
Ints = npt.NDArray[np.int64]
Texts = npt.NDArray[np.object_]


@dataclass(frozen=True)
class Substitutions:
    """Each value an agent used for a lost packet, one row each (N,).

    epoch : when used; agent : who used it; neighbour : whose packet was lost;
    fallback : it fell back to ``hold`` (no estimate to use); values : (N, d) ``x̃_j`` [m]
    """

    epoch: Ints
    agent: Ints
    neighbour: Ints
    fallback: Bools
    values: Array

    @classmethod
    def none(cls, d: int) -> Substitutions:
        empty = np.zeros(0, dtype=np.int64)
        return cls(empty, empty, empty, np.zeros(0, dtype=bool), np.zeros((0, d)))

    def errors(self, positions: Array) -> Array:
        """(N, d) ``x̃_j[k] − x_j[k]`` against ``positions`` (P, n, d); NaN where unknown."""
        out = np.full_like(self.values, np.nan)
        known = (self.epoch >= 0) & (self.epoch < len(positions))
        out[known] = self.values[known] - positions[self.epoch[known], self.neighbour[known] - 1]
        return out

    def known_errors(self, positions: Array) -> Array:
        """(N', d) the rows of :meth:`errors` where the neighbour's state is known [m]."""
        errors = self.errors(positions)
        return errors[np.isfinite(errors).all(axis=1)]


DECISION_COLUMNS = (
    "epoch",
    "phase",
    "link_class",
    "source",
    "target",
    "seq",
    "verdict",
    "delay_epochs",
    "delay_ms",
    "model",
    "state",
    "queue",
    "queue_depth",
    "sojourn_ms",
)


@dataclass(frozen=True)
class Decisions:
    """netem's verdict on each packet (docs/architecture.md "Wire"), one row each (N,).

    phase, link_class, verdict, model, state : text; queue : the capacity queue's name or
    None; queue_depth : its length when the packet came, −1 without a queue [packets];
    delay_ms, sojourn_ms : [ms], NaN where not known; coded : text columns also as codes
    into their few values, ``name → (codes (N,), values (k,))`` with ``values[codes]`` the
    column, where their maker had them (a recording's reader), so that millions of rows
    are not compared or factorized string by string
    """

    epoch: Ints
    phase: Texts
    link_class: Texts
    source: Ints
    target: Ints
    seq: Ints
    verdict: Texts
    delay_epochs: Ints
    delay_ms: Array
    model: Texts
    state: Texts
    queue: Texts
    queue_depth: Ints
    sojourn_ms: Array
    coded: Mapping[str, tuple[Ints, Texts]] = field(
        default_factory=dict, compare=False, repr=False, kw_only=True
    )

    @classmethod
    def of_rows(cls, rows: Sequence[tuple[Any, ...]]) -> Decisions:
        """From rows in :data:`DECISION_COLUMNS` order."""
        columns = list(zip(*rows, strict=True)) if rows else [()] * len(DECISION_COLUMNS)
        kinds = (int, object, object, int, int, int, object, int, float, object, object)
        out: dict[str, Any] = {
            name: np.array(col, dtype=np.int64 if kind is int else kind)
            for name, col, kind in zip(DECISION_COLUMNS, columns, kinds, strict=False)
        }
        out["queue"] = np.array(columns[11], dtype=object)
        out["queue_depth"] = np.array([-1 if v is None else v for v in columns[12]], dtype=np.int64)
        out["sojourn_ms"] = np.array([np.nan if v is None else v for v in columns[13]], dtype=float)
        return cls(**out)

    @classmethod
    def of_columns(cls, columns: Mapping[str, Sequence[Any]]) -> Decisions:
        """From a list per name of :data:`DECISION_COLUMNS`, rows in the same order."""
        out: dict[str, Any] = {}
        for name in DECISION_COLUMNS:
            values = columns[name]
            if name in ("epoch", "source", "target", "seq", "delay_epochs"):
                out[name] = np.array(values, dtype=np.int64).reshape(len(values))
            elif name == "queue_depth":
                out[name] = np.array([-1 if v is None else v for v in values], dtype=np.int64)
            elif name in ("delay_ms", "sojourn_ms"):
                out[name] = np.array(values, dtype=float).reshape(len(values))  # None → NaN
            else:
                out[name] = np.empty(len(values), dtype=object)
                out[name][:] = values
        return cls(**out)

    @cached_property  # the tables and the delivery matrix each ask, of millions of rows
    def on_time(self) -> Bools:
        """Delivered in its own epoch (passed or duplicated, not delayed)."""
        passed = self.text_in("verdict", ("pass", "duplicate"))
        return np.asarray(passed & (self.delay_epochs == 0), dtype=bool)

    def text_in(self, name: str, wanted: Sequence[str]) -> Bools:
        """(N,) whether text column ``name`` holds one of ``wanted``."""
        if name in self.coded:
            codes, values = self.coded[name]
            return np.isin(np.asarray(values, dtype=object), list(wanted))[codes]
        return np.isin(getattr(self, name), np.asarray(wanted, dtype=object))

    def delivery(self, links: Ints, count: int) -> tuple[Bools, Bools]:
        """(count, L) formation link ``links[l]`` delivered in time at epoch ``k``, and
        whether that delivery is known (a record of it)."""
        delivered = np.zeros((count, len(links)), dtype=bool)
        decided = np.zeros_like(delivered)
        rows = np.flatnonzero(self.text_in("link_class", ("formation",)))
        links = np.asarray(links, dtype=np.int64).reshape(-1, 2)
        if not len(rows) or not len(links):
            return delivered, decided
        base = int(max(links.max(), self.source[rows].max(), self.target[rows].max())) + 1
        codes = links[:, 0] * base + links[:, 1]
        order = np.argsort(codes, kind="stable")  # of a link listed twice, its last column
        source, target, k = self.source[rows], self.target[rows], self.epoch[rows]
        wanted = source * base + target
        at = np.maximum(np.searchsorted(codes[order], wanted, side="right") - 1, 0)
        column = order[at]
        ids = (source >= 0) & (target >= 0)
        keep = ids & (codes[column] == wanted) & (k >= 0) & (k < count)
        cell = k[keep] * len(links) + column[keep]
        # a later record of the same link and epoch wins, as it would written row by row
        _, last = np.unique(cell[::-1], return_index=True)
        chosen = len(cell) - 1 - last
        delivered.flat[cell[chosen]] = self.on_time[rows[keep][chosen]]
        decided.flat[cell[chosen]] = True
        return delivered, decided

    def judged(self) -> list[Judged]:
        """The drops and the queued packets, of every link class (:mod:`analysis.queues`)."""
        queued = np.array([q is not None for q in self.queue], dtype=bool)
        rows = np.flatnonzero((self.verdict == "drop") | queued)
        return [
            Judged(
                int(self.epoch[r]),
                str(self.verdict[r]),
                str(self.model[r]),
                self.queue[r],
                None if self.queue_depth[r] < 0 else int(self.queue_depth[r]),
                None if np.isnan(self.sojourn_ms[r]) else float(self.sojourn_ms[r]),
            )
            for r in rows.tolist()
        ]


class Skips(Protocol):
    """What a recording's trust gate refused (``recorder``'s ``Skipped``)."""

    @property
    def total(self) -> int: ...

    def by_reason(self) -> dict[str, int]: ...

    def describe(self, prefix: str = "") -> str: ...

    def as_json(self) -> dict[str, Any]: ...


@dataclass(frozen=True)
class Recorded:
    """What a recording adds to a run: its metadata, what its trust gate skipped, the
    recorder's live formation error (P,) [m] (NaN where absent) and why a process ended
    the run (a plug-in failed); with robot bodies in realtime, the agents' counts of their
    poses and commands (agent.body), summed over their final statuses."""

    metadata: Mapping[str, Mapping[str, str]]
    skipped: Skips
    formation_error: Array
    ended: tuple[str, ...] = ()
    files: tuple[str, ...] = ()
    robots: Mapping[str, int] = field(default_factory=dict)


@dataclass
class RunData:
    """A run as arrays; row ``i − 1`` is agent ``i``; ``P`` epochs of states, ``E`` of estimates.

    positions : (P, n, d) true positions [m], NaN where not recorded
    present : (P, n) in the team: its state of the epoch recorded (default: finite
    ``positions``; the simulator's bodies stay where they were, so it marks them itself)
    formation_error, shape_error : (P,) [m] over every edge
    estimates : (E, n, d) [m]; estimate_cov : (E, n, d, d) [m²]; observable : (E, n)
    estimated : (E,) the leader's estimate of epoch ``k`` is known (default: every epoch)
    delivered : (E, L) formation link ``links[l]`` delivered in time at epoch ``k``
    decided : (E, L) whether that delivery is known (always True from the simulator)
    healthy, tree : (E, m) per formation edge; components, rigidity_rank : (E,), −1 if unknown
    rigid : (E,) 1 rigid, 0 not, −1 unknown (default: from ``rigidity_rank``)
    substitution_errors : (N, d); nees_values : (M,); estimation_errors : (M, d) [m]
    headings : (P, n) [rad], NaN where not recorded; saturated : (P − 1, n) sub-steps of the step
    from epoch ``k`` with a clipped speed, −1 where not recorded (unicycle only, else None)
    substitutions : each value used for a lost packet (None: not known)
    decisions : netem's record of every packet (None: not known, only ``delivered``)
    recorded : what a recording adds (None for a simulated run)
    deadlines : a realtime run's deadline accounting, as ``report.md`` reads it
    computed : (P, n, d) the agents' states [m] where robots' measured poses replace them in
    ``positions``, NaN elsewhere (there ``positions`` are the states); None without
    measured poses (a realtime run with robot bodies has them)
    """

    label: str
    scenario: Scenario
    strategy: str
    seed: int
    positions: Array
    formation_error: Array
    shape_error: Array
    estimates: Array
    estimate_cov: Array
    observable: Bools
    delivered: Bools
    healthy: Bools
    tree: Bools
    components: Ints
    rigidity_rank: Ints
    substitution_errors: Array
    nees_values: Array
    estimation_errors: Array
    decided: Bools = field(default_factory=lambda: np.zeros(0, dtype=bool))
    source: str = "simulation"
    headings: Array | None = None
    saturated: Ints | None = None
    present: Bools = field(default_factory=lambda: np.zeros((0, 0), dtype=bool))
    rigid: Ints = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    estimated: Bools = field(default_factory=lambda: np.zeros(0, dtype=bool))
    substitutions: Substitutions | None = None
    decisions: Decisions | None = None
    recorded: Recorded | None = None
    deadlines: dict[str, Any] | None = None
    computed: Array | None = None

    def __post_init__(self) -> None:
        if self.decided.shape != self.delivered.shape:  # the simulator knows every delivery
            self.decided = np.ones_like(self.delivered, dtype=bool)
        if self.present.shape != self.positions.shape[:2]:
            self.present = membership.present(self.positions)
        if self.rigid.shape != self.rigidity_rank.shape:  # ranks say it where they are known
            s = self.scenario
            full = self.rigidity_rank == expected_rigidity_rank(s.n, s.dimension)
            self.rigid = np.where(self.rigidity_rank < 0, -1, full).astype(np.int64)
        if self.estimated.shape != self.estimates.shape[:1]:
            self.estimated = np.ones(len(self.estimates), dtype=bool)

    @property
    def links(self) -> Ints:
        """Directed formation links (L, 2), the columns of :attr:`delivered`."""
        return self.scenario.directed_links


__all__ = [
    "DECISION_COLUMNS",
    "Decisions",
    "Recorded",
    "RunData",
    "Skips",
    "Substitutions",
]
