"""The one registry of plug-ins: loss strategies, controllers and link models, by name.

A scenario names a plug-in by a registered name, found through the Python entry points of
any installed package (groups ``formation.strategies``, ``formation.controllers``,
``formation.link_models``), or by ``"package.module:name"`` for code not packaged yet. Our
own built-ins are entry points of this project's ``pyproject.toml``, found the same way: no
name is special. ``docs/plugins.md`` shows how to write each kind.

Loading imports the plug-in's module; every failure (not registered, an import that fails,
a missing attribute, an object of the wrong kind) is a :class:`PluginError` naming the kind,
the name and the problem, which the scenario loader turns into ``file: field = value; …``.
"""

from __future__ import annotations

import importlib
import inspect
from dataclasses import dataclass
from functools import cache
from importlib.metadata import EntryPoint, entry_points
from typing import Any

from formation.errors import PLUGIN_LABELS, PluginError, PluginKind

CHAPTER_STRATEGIES = ("zero", "hold", "estimate", "blend", "drop")  # in the chapter's order
GROUPS: dict[PluginKind, str] = {
    "strategy": "formation.strategies",
    "controller": "formation.controllers",
    "link_model": "formation.link_models",
}


@dataclass(frozen=True)
class Registered:
    """One registered plug-in: its name, where it is (``module:attribute``) and its package."""

    kind: PluginKind
    name: str
    target: str
    package: str  # the distribution that registers it, with its version

    def load(self) -> Any:
        return _import(self.kind, self.name, self.target)


def _package(ep: EntryPoint) -> str:
    dist = ep.dist
    return "?" if dist is None else f"{dist.name} {dist.version}"


@cache
def registered(kind: PluginKind) -> dict[str, Registered]:
    """Every plug-in of ``kind`` the installed packages register, by name, sorted.

    Two packages registering one name is an error: which one a scenario meant is unknown.
    """
    found: dict[str, Registered] = {}
    for ep in entry_points(group=GROUPS[kind]):
        entry = Registered(kind, ep.name, ep.value, _package(ep))
        other = found.get(ep.name)
        if other is not None and other.target != entry.target:
            raise PluginError(
                kind,
                ep.name,
                f"registered twice: by {other.package} ({other.target}) "
                f"and by {entry.package} ({entry.target})",
            )
        found[ep.name] = entry
    return dict(sorted(found.items()))


def names(kind: PluginKind) -> tuple[str, ...]:
    """The registered names of ``kind``, sorted."""
    return tuple(registered(kind))


def all_strategies() -> tuple[str, ...]:
    """Every registered loss strategy (by its entry point, not imported): the chapter's in its
    order, then the others by name."""
    others = [s for s in names("strategy") if s not in CHAPTER_STRATEGIES]
    return tuple(s for s in CHAPTER_STRATEGIES if s in names("strategy")) + tuple(others)


def is_reference(name: str) -> bool:
    """``"package.module:name"``: code named by its import path, not registered."""
    return ":" in name


def find(kind: PluginKind, name: str) -> Registered:
    """The plug-in ``name`` of ``kind``: a registered name or a ``"package.module:name"``."""
    if is_reference(name):
        return Registered(kind, name, name, "(not packaged)")
    entry = registered(kind).get(name)
    if entry is None:
        known = ", ".join(names(kind)) or "none"
        raise PluginError(
            kind,
            name,
            f"no {PLUGIN_LABELS[kind]} is registered under this name (registered: {known}; "
            f"or give 'package.module:name', or register it in the entry-point group "
            f"{GROUPS[kind]!r})",
        )
    return entry


def load(kind: PluginKind, name: str) -> Any:
    """The object plug-in ``name`` of ``kind`` names (imported once)."""
    return find(kind, name).load()


@cache
def _import(kind: PluginKind, name: str, target: str) -> Any:
    module_name, _, attr = target.partition(":")
    if not module_name or not attr:
        raise PluginError(kind, name, f"{target!r} is not 'package.module:name'")
    try:
        obj: Any = importlib.import_module(module_name)
    except Exception as exc:  # any import failure of a user's module is a clear error
        raise PluginError(
            kind, name, f"cannot import module {module_name!r} ({type(exc).__name__}: {exc})"
        ) from None
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise PluginError(kind, name, f"module {module_name!r} has no attribute {attr!r}")
        obj = getattr(obj, part)
    return obj


def check_callable(
    kind: PluginKind, name: str, what: str, fn: object, params: tuple[str, ...]
) -> None:
    """``fn`` is callable with exactly the positional parameters ``params``."""
    if not callable(fn):
        raise PluginError(kind, name, f"{what} = {fn!r} is not callable")
    try:
        sig = inspect.signature(fn)
    except (TypeError, ValueError):
        return  # a builtin or C function: its call is probed instead
    try:
        sig.bind(*params)
    except TypeError:
        want = ", ".join(params)
        raise PluginError(
            kind, name, f"{what} has the signature {sig}; expected ({want})"
        ) from None


__all__ = [
    "CHAPTER_STRATEGIES",
    "GROUPS",
    "Registered",
    "all_strategies",
    "check_callable",
    "find",
    "is_reference",
    "load",
    "names",
    "registered",
]
