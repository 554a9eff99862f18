"""The bulk kinds of a recording (agents' states, netem's decisions, the leader's estimates, the recorder's metrics) decoded by msgspec into structs made from their models.

A recording of 10,000 agents holds a million states, 44,000 decisions an epoch and an
estimate and metrics of 10,000 positions each; a pydantic model for each is most of the
cost of reading it. Each kind is decoded into the struct :func:`formation.structs.struct_of`
makes from its model; a payload msgspec refuses gets None from :func:`plain`, and the caller
validates it with the model, the one rule of a message's shape.
"""

from __future__ import annotations

from operator import attrgetter
from typing import Any

import msgspec
import numpy as np
import numpy.typing as npt

from formation.messages import (
    CoordinationState,
    Decision,
    DecisionBatch,
    EpochMetrics,
    LeaderEstimate,
)
from formation.structs import struct_of

DECODERS: dict[str, msgspec.json.Decoder[Any]] = {
    "agent_state": msgspec.json.Decoder(struct_of(CoordinationState)),
    "decision": msgspec.json.Decoder(struct_of(DecisionBatch)),
    "leader_estimate": msgspec.json.Decoder(struct_of(LeaderEstimate)),
    "metrics": msgspec.json.Decoder(struct_of(EpochMetrics)),
}


_INTS = ("epoch", "source", "target", "seq", "delay_epochs")
_DECISION_FIELDS = tuple(Decision.model_fields)
# the last batch whose columns were made, and them: one tuple, read once (threads share it)
_last: list[tuple[Any, dict[str, npt.NDArray[Any]]]] = [(None, {})]


def decision_columns(batch: Any) -> dict[str, npt.NDArray[Any]]:
    """A decision batch's columns as :class:`analysis.Decisions` holds them (``phase``
    repeated; None as −1 and NaN); made once for the batch the trust gate checks and the
    reader then keeps (the last batch's are remembered)."""
    last = _last[0]
    if last[0] is batch:
        return last[1]
    decisions, count = batch.decisions, len(batch.decisions)
    out: dict[str, npt.NDArray[Any]] = {"phase": np.full(count, batch.phase, dtype=object)}
    for name in _DECISION_FIELDS:
        values = map(attrgetter(name), decisions)
        if name in _INTS:
            out[name] = np.fromiter(values, np.int64, count)
        elif name == "delay_ms":
            out[name] = np.fromiter(values, float, count)
        else:
            out[name] = _column(name, list(values))
    _last[0] = (batch, out)
    return out


def _column(name: str, values: list[Any]) -> npt.NDArray[Any]:
    count = len(values)
    none = values.count(None) == count  # no capacity queue: the usual batch, made at once
    if name == "queue_depth":
        if none:
            return np.full(count, -1, dtype=np.int64)
        return np.array([-1 if v is None else v for v in values], dtype=np.int64)
    if name == "sojourn_ms":
        return np.full(count, np.nan) if none else np.array(values, dtype=float).reshape(count)
    if none:
        return np.full(count, None, dtype=object)
    column = np.empty(count, dtype=object)
    column[:] = values
    return column


def plain(kind: str, data: bytes) -> msgspec.Struct | None:
    """A ``kind`` payload (a key of :data:`DECODERS`) as a struct with its model's
    attributes and values, or None when only the model can say (then validate it with it)."""
    try:
        return DECODERS[kind].decode(data)  # type: ignore[no-any-return]
    except msgspec.DecodeError:  # ValidationError too
        return None


__all__ = ["DECODERS", "decision_columns", "plain"]
