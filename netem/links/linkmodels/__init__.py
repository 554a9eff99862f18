"""The layers of our link models, one module per model, and how a spec finds its layer.

Every link model is a plug-in (``formation.linkmodels``, docs/plugins.md): its spec names
its layer as ``"module:attribute"``; ours are ``netem.links.linkmodels.<tag>:LAYER``, each a
subclass of ``netem.links.layer.Layer`` overriding ``run`` (and, as the model needs,
``state_names``, ``packet``, ``problem``, ``loss_chain``, ``loss_rate``). The module's
docstring gives the model's semantics. To add one of ours: its spec in
``formation/linkmodels.py`` with the next free ``kind_code``, its entry point in
``pyproject.toml``, and its module here.
"""

from __future__ import annotations

from functools import cache
from typing import Any

from formation.linkmodels import BUILTIN_CODES, Spec, kind_code_of, spec_classes
from formation.plugin_registry import PluginError, Registered
from netem.links.layer import Layer, LinkModelError, enter_model


@cache
def _layer_class(cls: type[Spec]) -> type[Layer[Any]]:
    tag = cls.model_fields["model"].default
    layer = Registered("link_model", tag, cls.layer, "").load()
    if not (isinstance(layer, type) and issubclass(layer, Layer)):
        raise PluginError(
            "link_model", tag, f"layer {cls.layer!r} is {layer!r}; expected a netem Layer class"
        )
    return layer


def layer_of(spec: object) -> type[Layer[Any]] | None:
    """The layer class of a spec; None when ``spec`` is not a link model spec."""
    if not isinstance(spec, Spec):
        return None
    return _layer_class(type(spec))


def _enter_ours() -> dict[str, type[Layer[Any]]]:
    """Ours, entered in kind-code order, so that a table index is the kind code (0..11)."""
    ours = sorted(
        (kind_code_of(cls), tag, cls)
        for tag, cls in spec_classes().items()
        if kind_code_of(cls) < BUILTIN_CODES
    )
    layers: dict[str, type[Layer[Any]]] = {}
    for index, (code, tag, cls) in enumerate(ours):
        if code != index:
            raise LinkModelError("registry", f"our kind codes are not 0..n: {tag!r} has {code}")
        layers[tag] = _layer_class(cls)
        enter_model(tag, code, layers[tag].state_names)
    return layers


LAYERS: dict[str, type[Layer[Any]]] = _enter_ours()  # our tags → layer, in kind-code order

__all__ = ["LAYERS", "layer_of"]
