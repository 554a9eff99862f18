"""The registry of link models: tag → the layer that implements it, one module per model.

To add a model, touch two files:

1. ``formation/linkmodels.py``: its spec, a subclass of ``Spec`` with
   ``model: Literal["<tag>"] = "<tag>"``, appended at the end of the
   ``LinkModelSpec`` union. Scenarios accept the tag at once. Append, never
   insert: a model's position in the union is its kind code in every keyed draw. A model
   that decides by the link's length sets ``by_distance = True`` (``DISTANCE_MODELS``).
2. ``netem/links/linkmodels/<tag>.py``: its behaviour and closed forms, a subclass of
   ``netem.links.layer.Layer`` overriding ``run`` (and, as the model needs, ``state_names``,
   ``packet``, ``problem``, ``loss_chain``, ``loss_rate``), exported as ``LAYER``.
   The module's docstring gives the model's semantics.

Every module of this package is imported here; importing fails when a tag has no
module or a module no spec, so the two stay in step.
"""

from __future__ import annotations

import importlib
import pkgutil
from typing import Any

from formation.linkmodels import MODEL_NAMES, SPEC_OF, Spec
from netem.links.layer import Layer


def _discover() -> dict[str, type[Layer[Any]]]:
    found: dict[str, type[Layer[Any]]] = {}
    for info in pkgutil.iter_modules(__path__):
        layer = importlib.import_module(f"{__name__}.{info.name}").LAYER
        if not (isinstance(layer, type) and issubclass(layer, Layer)):
            raise ImportError(f"{__name__}.{info.name}.LAYER = {layer!r}; expected a Layer class")
        found[info.name] = layer
    missing = [tag for tag in MODEL_NAMES if tag not in found]
    unknown = sorted(set(found) - set(MODEL_NAMES))
    if missing or unknown:
        raise ImportError(
            f"{__name__}: no module for the tags {missing}, "
            f"no spec in formation.linkmodels for the modules {unknown}"
        )
    return {tag: found[tag] for tag in MODEL_NAMES}


LAYERS: dict[str, type[Layer[Any]]] = _discover()  # tag → layer, in MODEL_NAMES order
_BY_SPEC: dict[type[Spec], type[Layer[Any]]] = {SPEC_OF[tag]: c for tag, c in LAYERS.items()}
STATE_NAMES: dict[str, tuple[str, ...]] = {tag: c.state_names for tag, c in LAYERS.items()}


def layer_of(spec: object) -> type[Layer[Any]] | None:
    """The layer class of a spec; None when ``spec`` is not one of ``LinkModelSpec``."""
    return _BY_SPEC.get(type(spec))  # type: ignore[arg-type]


__all__ = ["LAYERS", "STATE_NAMES", "layer_of"]
