"""``logistic``: packet reception ratio ``PRR(d) = 1 / (1 + exp((d − d50_m) / width_m))``.

A distance model: the packet of epoch ``k`` on link ``i → j`` arrives iff its
keyed uniform ``u < PRR(d)``, ``d`` the distance between the true positions of
``i`` and ``j`` at ``k``; draws are independent over epochs and links. Closed
form: ``P(delivered | d) = PRR(d)``; half the packets arrive at ``d50_m``, and
the ratio falls from 88 % to 12 % over ``d50_m ± 2 width_m``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from formation.keyed_random import Stream
from formation.linkmodels import Logistic
from netem.layer import Bools, Floats, Ints, Keys, Layer, LayerOutput, LinkModelError

EXP_LIMIT = 700.0  # exp(700) is finite: PRR is 0 to the last bit beyond, with no overflow


class LogisticLayer(Layer[Logistic]):
    ranged = True

    def run(
        self, keys: Keys, epochs: Ints, carry: npt.NDArray[Any] | None
    ) -> tuple[LayerOutput, Any]:
        return LayerOutput(draws=keys.uniform(Stream.LOSS, self.kind, self.occ, epochs, 0)), None

    def keeps(self, draws: Floats | None, distance_m: Floats) -> Bools:
        if draws is None:
            raise LinkModelError(self.kind, "keeps needs the draws of the run")
        return np.asarray(draws < self.delivery_at(distance_m), dtype=np.bool_)

    def delivery_at(self, distance_m: Floats) -> Floats:
        s = self.spec
        z = np.minimum((np.asarray(distance_m, dtype=np.float64) - s.d50_m) / s.width_m, EXP_LIMIT)
        return np.asarray(1.0 / (1.0 + np.exp(z)), dtype=np.float64)


LAYER = LogisticLayer

__all__ = ["LAYER", "LogisticLayer"]
