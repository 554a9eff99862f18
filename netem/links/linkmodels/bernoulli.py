"""``bernoulli``: independent loss per epoch, optionally with tc's correlated uniform.

With ``correlation`` ``c`` the layer uses tc's correlated uniform
``u[k] = (1 - c) fresh[k] + c u[k-1]`` (``u[-1]`` a keyed draw) and drops when
``u[k] < p_loss``; its stationary loss rate is far below ``p_loss`` for ``c > 0``
(``loss_rate`` computes it, numerically). Without correlation the loss rate is
``p_loss`` and bursts are geometric, of mean ``1 / (1 - p_loss)``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from formation.keyed_random import Stream
from formation.linkmodels import Bernoulli
from netem.links.chains import ar1_uniform_cdf, run_ar1
from netem.links.layer import Floats, Ints, Keys, Layer, LayerOutput


class BernoulliLayer(Layer[Bernoulli]):
    def __init__(self, spec: Bernoulli, occurrence: int) -> None:
        super().__init__(spec, occurrence)
        self.p, self.c = spec.p_loss, spec.correlation
        self.stateful = self.c > 0.0

    def run(
        self, keys: Keys, epochs: Ints, carry: npt.NDArray[Any] | None
    ) -> tuple[LayerOutput, Any]:
        u = keys.uniform(Stream.LOSS, self.kind, self.occ, epochs, 0)
        if not self.stateful:
            return LayerOutput(drop=u < self.p), None
        if carry is None:
            carry = keys.uniform(Stream.LOSS, self.kind, self.occ, np.zeros(1, np.int64), 1)[:, 0]
        y = run_ar1(1.0 - self.c, self.c, u, carry)
        return LayerOutput(drop=y < self.p), y[:, -1]

    def loss_chain(self) -> tuple[Floats, Floats] | None:
        if self.c > 0.0:
            return None
        return np.ones((1, 1)), np.array([self.p])

    def loss_rate(self) -> float:
        if self.c > 0.0:
            return ar1_uniform_cdf(self.c, self.p)
        return super().loss_rate()


LAYER = BernoulliLayer

__all__ = ["LAYER", "BernoulliLayer"]
