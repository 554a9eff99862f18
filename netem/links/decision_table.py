"""A block of one link's decisions as a table: each distinct outcome made once.

Most epochs of a link decide the same (nothing happens), so a block of a piece's rows is
coded: epoch ``j`` is ``table[codes[j]]``, and only the few distinct rows become
:class:`~netem.links.layer_stack.Outcome` objects (:func:`coded_table`, or :class:`LazyTable` for a
packet's piece, asked for few of its epochs). :class:`netem.links.models.LinkModel` serves its
decisions from these.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import partial

import numpy as np
import numpy.typing as npt

from netem.links.layer_stack import Outcome, Piece, make_decision, state_string


def _rows(p: Piece) -> npt.NDArray[np.int64]:
    """Link 0's decisions of piece ``p``, one row an epoch: the first dropping layer, copies,
    delay [epochs], the bits of the delay [ms], reordered, then each layer's state code."""
    _, copies, de, dms, reo = p.final()
    rows = [p.first[0], copies[0], de[0], dms[0].view(np.int64), reo[0], p.states[0]]
    return np.column_stack(rows).astype(np.int64)


def _delays_ms(rows: npt.NDArray[np.int64]) -> list[float]:
    """The delays [ms] of rows of :func:`_rows`, from their bits."""
    delays: list[float] = rows[:, 3].view(np.float64).tolist()
    return delays


def _outcome(kinds: Sequence[str], row: Sequence[int], delay_ms: float) -> Outcome:
    """The decision of one row of :func:`_rows` with its delay [ms]; ``kinds`` are the stack's
    layer kinds."""
    first, copies, delay_epochs, _, reordered, *state = row
    model = kinds[first] if first >= 0 else ""
    return make_decision(
        model, copies, delay_epochs, delay_ms, bool(reordered), state_string(kinds, state)
    )


def _distinct(rows: npt.NDArray[np.int64]) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """``(index, inverse)`` of the distinct rows of ``rows``: ``rows == rows[index][inverse]``."""
    if (rows == rows[0]).all():  # the usual block: nothing happens on the link
        return np.zeros(1, np.int64), np.zeros(len(rows), np.int64)
    as_one = rows.view(np.dtype((np.void, rows.itemsize * rows.shape[1]))).ravel()
    _, index, inverse = np.unique(as_one, return_index=True, return_inverse=True)
    return index, inverse.reshape(-1)


def coded_table(pieces: Sequence[Piece]) -> tuple[npt.NDArray[np.int64], list[Outcome]]:
    """The pieces' decisions (link 0) as ``(codes, table)``: epoch ``j`` is ``table[codes[j]]``.

    Epochs with equal outcomes share one Outcome: only the few distinct rows are
    turned into Python objects.
    """
    table: list[Outcome] = []
    codes = []
    for p in pieces:
        kinds = [layer.kind for layer in p.stack.layers]
        rows = _rows(p)
        index, inverse = _distinct(rows)
        codes.append(inverse + len(table))
        picked = rows[index]
        table.extend(map(partial(_outcome, kinds), picked.tolist(), _delays_ms(picked)))
    return np.concatenate(codes), table


@dataclass
class LazyTable:
    """A piece's decisions coded like :func:`coded_table`'s, each distinct one made when first asked
    (a packet's piece is asked for few of its epochs)."""

    kinds: list[str]
    codes: list[int]
    rows: list[list[int]]  # the distinct rows
    delays_ms: list[float]  # theirs
    table: dict[int, Outcome] = field(default_factory=dict)

    @classmethod
    def of(cls, p: Piece) -> LazyTable:
        rows = _rows(p)
        index, inverse = _distinct(rows)
        picked = rows[index]
        kinds = [layer.kind for layer in p.stack.layers]
        return cls(kinds, inverse.tolist(), picked.tolist(), _delays_ms(picked))

    def at(self, j: int) -> Outcome:
        """The decision of the piece's epoch ``j``."""
        code = self.codes[j]
        out = self.table.get(code)
        if out is None:
            out = self.table[code] = _outcome(self.kinds, self.rows[code], self.delays_ms[code])
        return out
