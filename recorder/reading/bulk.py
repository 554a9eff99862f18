"""The bulk kinds of a recording (agents' states, netem's decisions, the leader's estimates, the recorder's metrics) decoded by msgspec into structs made from their models.

A recording of 10,000 agents holds a million states, 44,000 decisions an epoch and an
estimate and metrics of 10,000 positions each; a pydantic model for each is most of the
cost of reading it. Each kind is decoded into the struct :func:`formation.structs.struct_of`
makes from its model; a payload msgspec refuses gets None from :func:`plain`, and the caller
validates it with the model, the one rule of a message's shape.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import msgspec
import numpy as np
import numpy.typing as npt

from formation.messages import (
    Bundle,
    CoordinationState,
    DecisionBatch,
    EpochMetrics,
    Judgement,
    LeaderEstimate,
)
from formation.structs import struct_of

DECODERS: dict[str, msgspec.json.Decoder[Any]] = {
    "agent_state": msgspec.json.Decoder(struct_of(CoordinationState)),
    "state_bundle": msgspec.json.Decoder(struct_of(Bundle)),
    "decision": msgspec.json.Decoder(struct_of(DecisionBatch)),
    "leader_estimate": msgspec.json.Decoder(struct_of(LeaderEstimate)),
    "metrics": msgspec.json.Decoder(struct_of(EpochMetrics)),
}


_JUDGED = tuple(Judgement.model_fields)
_INTS = ("epoch", "source", "target", "seq", "judgement")
# the last batch whose columns were made, and them: one tuple, read once (threads share it)
_last: list[tuple[Any, dict[str, npt.NDArray[np.int64]]]] = [(None, {})]


def decision_columns(batch: Any) -> dict[str, npt.NDArray[np.int64]]:
    """A decision batch's record columns as arrays (``epoch``, ``source``, ``target``,
    ``seq``, ``judgement``); made once for the batch the trust gate checks and the reader
    then keeps (the last batch's are remembered).

    The batch's columns must have one length (:class:`recorder.reading.trust.Gate`
    checks); an id past 63 bits raises ``OverflowError``.
    """
    last = _last[0]
    if last[0] is batch:
        return last[1]
    records = batch.records
    count = len(records.source)
    out = {name: np.array(getattr(records, name), dtype=np.int64).reshape(count) for name in _INTS}
    _last[0] = (batch, out)
    return out


def judgement_columns(judgements: Sequence[Any]) -> dict[str, npt.NDArray[Any]]:
    """A batch's judgements as one column per field (None as −1 and NaN)."""
    count = len(judgements)
    out: dict[str, npt.NDArray[Any]] = {}
    for name in _JUDGED:
        values = [getattr(j, name) for j in judgements]
        if name in ("delay_epochs", "queue_depth"):
            out[name] = np.array([-1 if v is None else v for v in values], np.int64).reshape(count)
        elif name in ("delay_ms", "sojourn_ms"):
            out[name] = np.array(values, dtype=float).reshape(count)  # None → NaN
        else:
            out[name] = np.empty(count, dtype=object)
            out[name][:] = values
    return out


def plain(kind: str, data: bytes) -> msgspec.Struct | None:
    """A ``kind`` payload (a key of :data:`DECODERS`) as a struct with its model's
    attributes and values, or None when only the model can say (then validate it with it)."""
    try:
        return DECODERS[kind].decode(data)  # type: ignore[no-any-return]
    except msgspec.DecodeError:  # ValidationError too
        return None


__all__ = ["DECODERS", "decision_columns", "judgement_columns", "plain"]
