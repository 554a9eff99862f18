"""netem's decision batches as recordings made before the columns hold them: a list of records,
each with its link, epoch, seq and decision, read into a :class:`~formation.messages.DecisionBatch`
of columns (so every reader of a recording takes one shape)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, ValidationError

from formation.messages import LINK_CLASS_OF, Decision, DecisionBatch


class RowBatch(BaseModel):
    """A decision batch as rows: one :class:`~formation.messages.Decision` per record."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    run_id: str
    sender: str
    seq: int
    epoch: int
    stamp_ns: int
    kind: Literal["decisions"] = "decisions"
    phase: Literal["state", "report", "estimate"]
    decisions: list[Decision]


def row_batch(data: bytes) -> DecisionBatch | None:
    """``data`` as a batch of columns if it is a batch of rows whose records are all of its
    phase's link class, else None."""
    try:
        rows = RowBatch.model_validate_json(data)
    except (ValidationError, ValueError, UnicodeDecodeError):
        return None
    if any(d.link_class != LINK_CLASS_OF[rows.phase] for d in rows.decisions):
        return None
    header = rows.model_dump(include={"run_id", "sender", "seq", "epoch", "stamp_ns"})
    try:
        return DecisionBatch.of_rows(phase=rows.phase, decisions=rows.decisions, **header)
    except ValidationError:  # a header the columns' model refuses (a negative seq)
        return None


__all__ = ["RowBatch", "row_batch"]
