"""The bulk kinds of a recording (agents' states, netem's decisions, the leader's estimates, the recorder's metrics) decoded by msgspec into structs made from their models.

A recording of 10,000 agents holds a million states, 44,000 decisions an epoch and an
estimate and metrics of 10,000 positions each; a pydantic model for each is most of the
cost of reading it. :func:`struct_of` builds a
msgspec struct from a pydantic model, field by field (its type, its ``ge`` bound, its
default; no unknown field), and msgspec decodes strictly: it takes a value only where
the model would read it as it is (an int for an int, an int or a float for a float, a
literal one of its values). A payload msgspec refuses (``1.0`` for an int, an int past 64
bits, a number past a double) gets None from :func:`plain`, and the caller validates it
with the model: the model stays the one rule of a message's shape, this is a shortcut to
its answer. A model with a rule :func:`struct_of` cannot carry (a validator, another
constraint) is refused when this module loads.
"""

from __future__ import annotations

import types
from operator import attrgetter
from typing import Annotated, Any, Union, get_args, get_origin

import annotated_types
import msgspec
import numpy as np
import numpy.typing as npt
from pydantic import BaseModel

from formation.messages import (
    CoordinationState,
    Decision,
    DecisionBatch,
    EpochMetrics,
    LeaderEstimate,
)


def _field_type(annotation: Any) -> Any:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return struct_of(annotation)
    origin, args = get_origin(annotation), get_args(annotation)
    if origin is list:
        return list[_field_type(args[0])]  # type: ignore[misc]
    if origin in (Union, types.UnionType):
        return Union[tuple(_field_type(a) for a in args)]  # noqa: UP007
    return annotation  # int, float, str, bool, a Literal, tuple[int, int]


def _bounded(annotation: Any, low: int) -> Any:
    """``annotation`` at least ``low``; on an optional one, its value when given."""
    if get_origin(annotation) in (Union, types.UnionType):
        args = get_args(annotation)
        return Union[tuple(a if a is type(None) else _bounded(a, low) for a in args)]  # noqa: UP007
    return Annotated[annotation, msgspec.Meta(ge=low)]


def struct_of(model: type[BaseModel]) -> type[msgspec.Struct]:
    """A frozen msgspec struct with ``model``'s fields, types, ``ge`` bounds and defaults."""
    decorators = model.__pydantic_decorators__
    if decorators.field_validators or decorators.model_validators or decorators.validators:
        raise TypeError(f"{model.__name__} has a validator msgspec cannot apply")
    fields: list[tuple[str, Any] | tuple[str, Any, Any]] = []
    for name, info in model.model_fields.items():
        kind = _field_type(info.annotation)
        for rule in info.metadata:
            if not isinstance(rule, annotated_types.Ge) or not isinstance(rule.ge, int):
                raise TypeError(f"{model.__name__}.{name}: {rule!r} has no msgspec form here")
            kind = _bounded(kind, rule.ge)
        fields.append((name, kind) if info.is_required() else (name, kind, info.default))
    # gc=False: decoded JSON holds no cycles, and a recording is millions of these structs
    return msgspec.defstruct(
        model.__name__, fields, kw_only=True, frozen=True, forbid_unknown_fields=True, gc=False
    )


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


__all__ = ["DECODERS", "decision_columns", "plain", "struct_of"]
