"""Whether a decision batch's columns fit together, before anything reads them as a table."""

from __future__ import annotations

from typing import Any

import numpy as np

from formation.messages import DecisionColumns
from recorder.reading.skips import INVALID, Skip

_COLUMNS = tuple(DecisionColumns.model_fields)


def check_shape(batch: Any) -> None:
    """Raise :class:`Skip` unless the batch's record columns have one length and each
    judgement index is one of its judgements', naming the columns or the record at fault."""
    records = batch.records
    lengths = [len(getattr(records, name)) for name in _COLUMNS]
    if len(set(lengths)) > 1:
        sizes = ", ".join(f"{n} {k}" for n, k in zip(_COLUMNS, lengths, strict=True))
        raise Skip(INVALID, f"decision columns of unequal lengths: {sizes}")
    index, count = records.judgement, len(batch.judgements)
    try:
        at = np.array(index, dtype=np.int64)
        if not len(at) or (at.min() >= 0 and at.max() < count):
            return
    except OverflowError:
        pass
    r, bad = next((r, j) for r, j in enumerate(index) if not 0 <= j < count)
    raise Skip(INVALID, f"record {r}: judgement {bad}, but the batch has {count} judgements")


__all__ = ["check_shape"]
