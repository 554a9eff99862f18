"""The wire models as msgspec structs: a shortcut to their validation, for messages read in bulk.

A pool of hundreds of agents reads thousands of deliveries and packets an epoch, a recording
of 10,000 agents a million states; a pydantic model for each is most of the cost.
:func:`struct_of` builds a msgspec struct from a pydantic model, field by field (its type,
its ``ge`` bound, its default; no unknown field), and msgspec decodes strictly: it takes a
value only where the model would read it as it is (an int for an int, an int or a float for
a float, a literal one of its values). A payload msgspec refuses (``1.0`` for an int, an int
past 64 bits, a number past a double) gets None from :func:`plain_of`, and the caller
validates it with the model: the model stays the one rule of a message's shape, this is a
shortcut to its answer. A model with a rule :func:`struct_of` cannot carry (a validator,
another constraint) is refused.
"""

from __future__ import annotations

import types
from typing import Annotated, Any, Union, get_args, get_origin

import annotated_types
import msgspec
from pydantic import BaseModel


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


_DECODERS: dict[type[BaseModel], msgspec.json.Decoder[Any]] = {}


def decoder_of(model: type[BaseModel]) -> msgspec.json.Decoder[Any]:
    """The decoder of ``model``'s struct, made once (a node makes its own before the run's
    clock starts, so its first epoch does not)."""
    decoder = _DECODERS.get(model)
    if decoder is None:
        decoder = _DECODERS[model] = msgspec.json.Decoder(struct_of(model))
    return decoder


def plain_of(model: type[BaseModel], data: bytes | str) -> Any:
    """``data`` as a struct with ``model``'s attributes and values, or None when only the
    model can say (then validate it with it)."""
    try:
        return decoder_of(model).decode(data)
    except msgspec.DecodeError:  # ValidationError too
        return None


__all__ = ["decoder_of", "plain_of", "struct_of"]
