"""Whether a decision batch's columns fit together and lie within the scenario, before
anything reads them as a table."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from formation import keys
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


def records_in_range(
    epoch: npt.NDArray[np.int64],
    source: npt.NDArray[np.int64],
    target: npt.NDArray[np.int64],
    latest: int,
    n: int,
    link_class: str,
) -> bool:
    """Whether every record's epoch is in ``0..latest``, its ends in ``0..n`` and, for a
    report or an estimate, its link one of the leader's control links of that direction
    (a formation link's membership is the caller's: it keeps the scenario's links)."""
    ends = np.concatenate([source, target])
    if not ((epoch >= 0) & (epoch <= latest)).all() or not ((ends >= 0) & (ends <= n)).all():
        return False
    leader = keys.LEADER_ENDPOINT
    if link_class == "report":
        return bool(((target == leader) & (source != leader)).all())
    if link_class == "estimate":
        return bool(((source == leader) & (target != leader)).all())
    return True


__all__ = ["check_shape", "records_in_range"]
