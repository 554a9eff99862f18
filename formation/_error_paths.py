"""Where a validation error is in a scenario: pydantic's ``loc`` as the file's field path.

pydantic adds labels of union members and validators to ``loc`` (``"line"``,
``"delay"``); the path a user reads names only fields, so those labels are dropped
by walking the models' fields from the root model.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, get_args

from pydantic import BaseModel

from formation.errors import NO_VALUE


def field_loc(root: type[BaseModel], loc: Sequence[int | str]) -> list[int | str]:
    """``loc`` without pydantic's labels of union members and validators (``"line"``, ``"delay"``).

    A name is kept when a model the path is in has a field or alias of that name, or
    when it comes last (an unknown key); any other name is a label pydantic added.
    """
    models: list[type[BaseModel]] = [root]
    out: list[int | str] = []
    for k, part in enumerate(loc):
        if isinstance(part, int):
            out.append(part)
            continue
        fields = [f for m in models for n, f in m.model_fields.items() if part in (n, f.alias)]
        if fields:
            models = [m for f in fields for m in models_in(f.annotation)]
        if fields or k == len(loc) - 1:
            out.append(part)
    return out


def models_in(annotation: Any) -> list[type[BaseModel]]:
    """The models a field's type can hold, through tuples, unions and ``Annotated``."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    return [m for arg in get_args(annotation) for m in models_in(arg)]


def loc_path(root: type[BaseModel], loc: Sequence[int | str]) -> str:
    out = ""
    for part in field_loc(root, loc):
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else part)
    return out


def lookup(root: type[BaseModel], data: Any, loc: Sequence[int | str]) -> object:
    cur = data
    for part in field_loc(root, loc):
        if isinstance(cur, dict) and part in cur:
            cur = cur[part]
            continue
        if isinstance(cur, list | tuple) and isinstance(part, int) and part < len(cur):
            cur = cur[part]
            continue
        return NO_VALUE
    return cur


__all__ = ["field_loc", "loc_path", "lookup", "models_in"]
