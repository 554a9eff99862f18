"""``up``: the link always delivers; the identity layer of a stack."""

from __future__ import annotations

from formation.linkmodels import Up
from netem.links.layer import Floats, Layer, lossless


class UpLayer(Layer[Up]):
    def loss_chain(self) -> tuple[Floats, Floats]:
        return lossless()


LAYER = UpLayer

__all__ = ["LAYER", "UpLayer"]
