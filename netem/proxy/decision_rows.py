"""A phase's streams and their links' decisions, taken for a block of epochs at once.

A stream is one inbound key's packets: an agent's states fan out on its out-links, a
report goes to the leader, the leader's estimate for ``i`` to ``i``. A link's model decides
packet 0 of an epoch from its key alone (docs/model.md §4), so a block of epochs is decided
at once, vectorised (:meth:`LinkModel.coded`), and each epoch of a stream gets a
:class:`Row`, one decision per link, shared by the epochs that decide alike. A distance
layer needs the epoch's lengths: its row holds the decision before those layers, which
stands for a link within :meth:`LinkModel.reach` (given with the row); the lockstep core asks
the model about the others.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from formation.keys import LEADER_ENDPOINT
from netem.links.layer_stack import Outcome
from netem.links.models import LinkModel
from netem.proxy.routes import Link, Links, Phase

BLOCK = 1024  # epochs decided at once
KEEP_BLOCKS = 2  # lockstep never lags a block behind


class Stream(NamedTuple):
    """Where one inbound key's packets go: its links, their receivers and models."""

    links: tuple[Link, ...]
    receivers: tuple[int, ...]
    models: tuple[LinkModel, ...]


class Row(NamedTuple):
    """A stream's decisions of packet 0 of an epoch, one per link (None where only the model
    knows: past a failing layer, under a realtime window); ``plain`` when every link passes it
    as it is (one copy, no delay)."""

    decisions: tuple[Outcome | None, ...]
    plain: bool


def row_of(decisions: tuple[Outcome | None, ...]) -> Row:
    return Row(decisions, all(d is not None and d.verdict == "pass" for d in decisions))


_Block = dict[int, tuple[list[Row], list[list[float]] | None]]  # stream → rows, reach [m]


class DecisionRows:
    """One phase's streams and each epoch's row of decisions per stream."""

    def __init__(self, streams: dict[int, Stream], block: int = BLOCK) -> None:
        self.streams = streams
        self._block = block
        self._blocks: dict[int, _Block] = {}
        self.ranged: dict[int, bool] = {}
        self.invalidate()

    def row(self, stream: int, epoch: int) -> tuple[Row, list[float] | None]:
        """``stream``'s row at ``epoch``, and each link's reach [m] then if a link has a
        distance model (else None)."""
        k = epoch // self._block
        blk = self._blocks.get(k)
        if blk is None:
            blk = self._compute(k)
        rows, reach = blk[stream]
        j = epoch - k * self._block
        return rows[j], None if reach is None else reach[j]

    def at(self, epoch: int) -> tuple[_Block, int]:
        """Every stream's rows and reach of ``epoch``'s block, and ``epoch``'s index in it
        (:meth:`row` of many streams)."""
        k = epoch // self._block
        blk = self._blocks.get(k)
        if blk is None:
            blk = self._compute(k)
        return blk, epoch - k * self._block

    def invalidate(self) -> None:
        """A link's model changed: decide again."""
        self._blocks.clear()
        self.ranged = {sid: any(m.ranged for m in s.models) for sid, s in self.streams.items()}

    def _compute(self, k: int) -> _Block:
        start, size = k * self._block, self._block
        interned: dict[int, int] = {}  # id of a decision → its index in ``table``
        table: list[Outcome | None] = []
        blk: _Block = {}
        for sid, s in self.streams.items():
            ids = np.empty((len(s.models), size), dtype=np.int64)
            for i, model in enumerate(s.models):
                codes, own = model.coded(start, size, before_distance=True)
                index = []
                for d in own:
                    x = interned.get(id(d))
                    if x is None:  # the table keeps d alive: its id is not reused
                        x = interned[id(d)] = len(table)
                        table.append(d)
                    index.append(x)
                ids[i] = np.asarray(index, dtype=np.int64)[codes]
            blk[sid] = (_rows(ids, table), _reach(s, start, size) if self.ranged[sid] else None)
        while len(self._blocks) >= KEEP_BLOCKS:
            del self._blocks[next(iter(self._blocks))]
        self._blocks[k] = blk
        return blk


def _rows(ids: npt.NDArray[np.int64], table: list[Outcome | None]) -> list[Row]:
    """Each epoch's row from the decisions' indices into ``table``, ``(links, epochs)``."""
    if (ids == ids[:, :1]).all():  # the usual block: every epoch decides alike
        return [row_of(tuple(table[i] for i in ids[:, 0].tolist()))] * ids.shape[1]
    columns, inverse = np.unique(ids, axis=1, return_inverse=True)
    distinct = [row_of(tuple(table[i] for i in c)) for c in columns.T.tolist()]
    return [distinct[j] for j in inverse.reshape(-1).tolist()]


def _reach(s: Stream, start: int, size: int) -> list[list[float]]:
    """Each epoch's reach [m] of each link of ``s`` (:meth:`LinkModel.reach`; inf: no distance
    layer)."""
    return np.array([m.reach(start, size) for m in s.models]).T.tolist()  # type: ignore[no-any-return]


def decision_rows(links: Links) -> dict[Phase, DecisionRows]:
    """Each phase's streams: an agent's states on its out-links, its report to the leader, the
    leader's estimate for ``i`` to ``i``."""

    def stream(chosen: list[Link]) -> Stream:
        models = tuple(links.models[link] for link in chosen)
        return Stream(tuple(chosen), tuple(dst for _, _, dst in chosen), models)

    agents, out_links = links.agents, links.out_links
    return {
        "state": DecisionRows(
            {s: stream([("formation", s, d) for d in out_links[s]]) for s in agents if out_links[s]}
        ),
        "report": DecisionRows({s: stream([("report", s, LEADER_ENDPOINT)]) for s in agents}),
        "estimate": DecisionRows({d: stream([("estimate", LEADER_ENDPOINT, d)]) for d in agents}),
    }


__all__ = ["BLOCK", "DecisionRows", "Row", "Stream", "decision_rows", "row_of"]
