"""``duplicate``: a delivered packet gets an extra copy w.p. ``p`` (tc ``duplicate P``).

Both copies share the delay. Unlike tc, a dropped packet is dropped whole, so
loss rates keep their closed forms. Drawn per packet, keyed by ``(epoch, seq)``.
"""

from __future__ import annotations

from typing import Any

import numpy.typing as npt

from formation.keyed_random import Stream
from formation.linkmodels import Duplicate
from netem.links.layer import Bools, Floats, Ints, Keys, Layer, LayerOutput, lossless


class DuplicateLayer(Layer[Duplicate]):
    def __init__(self, spec: Duplicate, occurrence: int) -> None:
        super().__init__(spec, occurrence)
        self.p = spec.p

    def draw(self, keys: Keys, epochs: Ints, seq: int) -> Bools:
        return keys.uniform(Stream.DUPLICATE, self.kind, self.occ, epochs, seq) < self.p

    def run(
        self, keys: Keys, epochs: Ints, carry: npt.NDArray[Any] | None
    ) -> tuple[LayerOutput, Any]:
        return LayerOutput(dup=self.draw(keys, epochs, 0)), None

    def packet(self, keys: Keys, epochs: Ints, seq: int, prev: Floats | None) -> LayerOutput:
        return LayerOutput(dup=self.draw(keys, epochs, seq))

    def loss_chain(self) -> tuple[Floats, Floats]:
        return lossless()


LAYER = DuplicateLayer

__all__ = ["LAYER", "DuplicateLayer"]
