"""``range``: a hard cutoff, delivered iff the link's length ``d ≤ max_range_m``.

A distance model: the verdict of link ``i → j`` at epoch ``k`` uses the true
positions of both ends at ``k`` (``Layer.keeps``, its reach ``max_range_m``); it has no draws. Closed form:
``P(delivered | d) = 1[d ≤ max_range_m]``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from formation.linkmodels import Range
from netem.links.layer import Floats, Ints, Keys, Layer, LayerOutput


class RangeLayer(Layer[Range]):
    ranged = True

    def run(
        self, keys: Keys, epochs: Ints, carry: npt.NDArray[Any] | None
    ) -> tuple[LayerOutput, Any]:
        return LayerOutput(
            reach_m=np.full((keys.n_links, epochs.shape[0]), self.spec.max_range_m)
        ), None

    def delivery_at(self, distance_m: Floats) -> Floats:
        return np.asarray(distance_m <= self.spec.max_range_m, dtype=np.float64)


LAYER = RangeLayer

__all__ = ["LAYER", "RangeLayer"]
