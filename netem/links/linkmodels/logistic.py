"""``logistic``: packet reception ratio ``PRR(d) = 1 / (1 + exp((d − d50_m) / width_m))``.

A distance model: the packet of epoch ``k`` on link ``i → j`` arrives iff its
keyed uniform ``u ≤ PRR(d)``, ``d`` the distance between the true positions of
``i`` and ``j`` at ``k``; draws are independent over epochs and links. The run turns
``u`` into its reach ``d50_m + width_m ln((1 − u) / u)``, the longest link that
delivers, so a verdict is one comparison ``d ≤ reach`` (``Layer.keeps``). Closed
form: ``P(delivered | d) = PRR(d)``; half the packets arrive at ``d50_m``, and
the ratio falls from 88 % to 12 % over ``d50_m ± 2 width_m``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from formation.keyed_random import Stream
from formation.linkmodels import Logistic
from netem.links.layer import Floats, Ints, Keys, Layer, LayerOutput

EXP_LIMIT = 700.0  # exp(700) is finite: PRR is 0 to the last bit beyond, with no overflow


class LogisticLayer(Layer[Logistic]):
    ranged = True

    def run(
        self, keys: Keys, epochs: Ints, carry: npt.NDArray[Any] | None
    ) -> tuple[LayerOutput, Any]:
        u = keys.uniform(Stream.LOSS, self.kind, self.occ, epochs, 0)
        with np.errstate(divide="ignore"):  # u = 0 reaches everywhere
            reach = self.spec.d50_m + self.spec.width_m * (np.log1p(-u) - np.log(u))
        return LayerOutput(reach_m=reach), None

    def delivery_at(self, distance_m: Floats) -> Floats:
        s = self.spec
        z = np.minimum((np.asarray(distance_m, dtype=np.float64) - s.d50_m) / s.width_m, EXP_LIMIT)
        return np.asarray(1.0 / (1.0 + np.exp(z)), dtype=np.float64)


LAYER = LogisticLayer

__all__ = ["LAYER", "LogisticLayer"]
