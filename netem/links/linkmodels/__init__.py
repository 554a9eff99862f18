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

from formation.errors import PluginError
from formation.linkmodels import Spec, spec_classes
from formation.plugin_registry import Registered
from netem.links.layer import Layer


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


def layers() -> dict[str, type[Layer[Any]]]:
    """Every registered link model's layer, by tag (imports every link model plug-in)."""
    return {tag: _layer_class(cls) for tag, cls in spec_classes().items()}


__all__ = ["layer_of", "layers"]
