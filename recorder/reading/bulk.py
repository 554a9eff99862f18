"""The bulk kinds of a recording, agents' states and netem's decisions, decoded by orjson where exact JSON types vouch for them.

A recording of 10,000 agents holds a million states and 44,000 decisions an epoch; a
pydantic model for each is most of the cost of reading it. :func:`plain_state` and
:func:`plain_decisions` decode a payload with orjson and accept it only when every field
has exactly the JSON type its model reads without conversion (a float a float, an int an
int, a literal one of its values, no unknown field, every required one), so what they
return holds the very values the model would. Any other payload (an int where a float is
due, a number out of orjson's range, bad UTF-8) gets None, and the caller validates it with
the model: the model stays the one rule of a message's shape, this is a shortcut to its
answer.
"""

from __future__ import annotations

from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

import orjson

from formation.messages import CoordinationState, Decision, DecisionBatch, Substitute

Check = Callable[[Any], bool]


def _int_at_least(low: int | None) -> Check:
    return lambda v: type(v) is int and (low is None or v >= low)


def _str(v: Any) -> bool:
    return type(v) is str


def _floats(v: Any) -> bool:
    return type(v) is list and all(type(x) is float for x in v)


def _optional(check: Check) -> Check:
    return lambda v: v is None or check(v)


def _substitutes(v: Any) -> bool:
    return type(v) is list and all(_fits(s, SUBSTITUTE_FIELDS, _SUB_REQUIRED) for s in v)


# Each field of the models, with the JSON type the model takes as it is (and its bound).
SUBSTITUTE_FIELDS: dict[str, Check] = {
    "neighbour": _int_at_least(None),
    "value": _floats,
    "fallback": lambda v: type(v) is bool,
}
STATE_FIELDS: dict[str, Check] = {
    "run_id": _str,
    "sender": _str,
    "seq": _int_at_least(0),
    "epoch": _int_at_least(-1),
    "stamp_ns": _int_at_least(0),
    "kind": lambda v: v == "state" and type(v) is str,
    "agent": _int_at_least(None),
    "position": _floats,
    "velocity": _optional(_floats),
    "substituted": _substitutes,
    "heading": _optional(lambda v: type(v) is float),
    "saturated": _optional(_int_at_least(0)),
}
_REQUIRED = frozenset(n for n, f in CoordinationState.model_fields.items() if f.is_required())
_SUB_REQUIRED = frozenset(n for n, f in Substitute.model_fields.items() if f.is_required())
_DEFAULTS = {n: f.default for n, f in CoordinationState.model_fields.items() if n not in _REQUIRED}
_SUB_DEFAULTS = {n: f.default for n, f in Substitute.model_fields.items() if n not in _SUB_REQUIRED}


def _fits(obj: Any, fields: dict[str, Check], required: frozenset[str]) -> bool:
    if type(obj) is not dict:
        return False
    names = obj.keys()
    if not (required <= names and names <= fields.keys()):
        return False
    return all(fields[name](value) for name, value in obj.items())


def _literal(*values: str) -> Check:
    return lambda v: type(v) is str and v in values


BATCH_FIELDS: dict[str, Check] = {
    **{name: STATE_FIELDS[name] for name in ("run_id", "sender", "seq", "epoch", "stamp_ns")},
    "kind": _literal("decisions"),
    "phase": _literal("state", "report", "estimate"),
    "decisions": lambda v: type(v) is list and all(type(d) is dict for d in v),
}
_NONE = type(None)
# A decision's fields as columns: the JSON types each takes as it is, and its values if a literal.
DECISION_FIELDS: dict[str, tuple[frozenset[type], frozenset[str] | None]] = {
    "source": (frozenset({int}), None),
    "target": (frozenset({int}), None),
    "link_class": (frozenset({str}), frozenset({"formation", "report", "estimate"})),
    "epoch": (frozenset({int}), None),
    "seq": (frozenset({int}), None),
    "verdict": (frozenset({str}), frozenset({"pass", "drop", "duplicate", "delayed"})),
    "delay_epochs": (frozenset({int}), None),
    "delay_ms": (frozenset({float}), None),
    "model": (frozenset({str}), None),
    "state": (frozenset({str}), None),
    "queue": (frozenset({str, _NONE}), None),
    "queue_depth": (frozenset({int, _NONE}), None),
    "sojourn_ms": (frozenset({float, _NONE}), None),
}
_BATCH_REQUIRED = frozenset(n for n, f in DecisionBatch.model_fields.items() if f.is_required())
_BATCH_DEFAULTS = {
    n: f.default for n, f in DecisionBatch.model_fields.items() if not f.is_required()
}
_DECISION = Decision.model_fields


def _column(decisions: list[dict[str, Any]], name: str) -> list[Any] | None:
    """One field of every decision, if each has its JSON type (and value, for a literal)."""
    field = _DECISION[name]
    if field.is_required():
        column = [d[name] for d in decisions]  # KeyError: one lacks it
    else:
        default = field.default
        column = [d.get(name, default) for d in decisions]
    types, values = DECISION_FIELDS[name]
    if not set(map(type, column)) <= types or (values is not None and not set(column) <= values):
        return None
    return column


def plain_decisions(data: bytes) -> SimpleNamespace | None:
    """A decision batch as an object with :class:`DecisionBatch`'s header attributes and
    ``columns``, each decision field a list in batch order (``decisions`` is None), or None
    when only the model can say."""
    try:
        obj = orjson.loads(data)
    except orjson.JSONDecodeError:
        return None
    if not _fits(obj, BATCH_FIELDS, _BATCH_REQUIRED):
        return None
    decisions = obj.pop("decisions")
    if decisions and not set().union(*map(dict.keys, decisions)) <= DECISION_FIELDS.keys():
        return None
    try:
        columns = {name: _column(decisions, name) for name in DECISION_FIELDS}
    except KeyError:
        return None
    if any(column is None for column in columns.values()):
        return None
    return SimpleNamespace(**{**_BATCH_DEFAULTS, **obj, "decisions": None, "columns": columns})


def plain_state(data: bytes) -> SimpleNamespace | None:
    """A state payload as an object with :class:`CoordinationState`'s attributes and values,
    or None when only the model can say (then validate it with the model)."""
    try:
        obj = orjson.loads(data)
    except orjson.JSONDecodeError:
        return None
    if not _fits(obj, STATE_FIELDS, _REQUIRED):
        return None
    subs = [SimpleNamespace(**{**_SUB_DEFAULTS, **s}) for s in obj.get("substituted", ())]
    return SimpleNamespace(**{**_DEFAULTS, **obj, "substituted": subs})


__all__ = [
    "BATCH_FIELDS",
    "DECISION_FIELDS",
    "STATE_FIELDS",
    "SUBSTITUTE_FIELDS",
    "plain_decisions",
    "plain_state",
]
