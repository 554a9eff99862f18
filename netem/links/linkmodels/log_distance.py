"""``log_distance``: log-distance path loss, log-normal shadowing, a receiver threshold.

The form of Rappaport, *Wireless Communications* (2nd ed., §4.9, eq. 4.69):
``PL(d) = PL(d0) + 10 n log10(d / d0) + X_σ`` [dB], and the packet arrives iff the
received power ``P_t − PL(d) ≥ sensitivity_dbm``. ``d`` is the distance between
the link's ends' true positions at the epoch; below ``d0_m`` it counts as ``d0_m``
(the form holds in the far field only). Shadowing ``X_σ`` is keyed per link and
epoch: ``X[k] = c X[k−1] + sqrt(1 − c²) σ N[k]`` with ``c = shadowing_correlation``
and ``X[−1] = σ N`` (a keyed draw), so its marginal is N(0, σ²) at every epoch.

Closed form, with the margin ``m(d) = P_t − PL(d0) − 10 n log10(d / d0) − sensitivity``:
``P(delivered | d) = Φ(m(d) / σ)`` (Φ the standard normal CDF), ``1[m(d) ≥ 0]``
without shadowing. With correlation the rate is the same, the losses come in runs.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.special import ndtr

from formation.keyed_random import Stream
from formation.linkmodels import LogDistance
from netem.links.chains import run_ar1
from netem.links.layer import Floats, Ints, Keys, Layer, LayerOutput


class LogDistanceLayer(Layer[LogDistance]):
    ranged = True

    def __init__(self, spec: LogDistance, occurrence: int) -> None:
        super().__init__(spec, occurrence)
        self.c, self.sigma = spec.shadowing_correlation, spec.sigma_db
        self.stateful = self.c > 0.0 and self.sigma > 0.0

    def run(
        self, keys: Keys, epochs: Ints, carry: npt.NDArray[Any] | None
    ) -> tuple[LayerOutput, Any]:
        shape = (keys.n_links, epochs.shape[0])
        if self.sigma == 0.0:
            return LayerOutput(reach_m=self.reach(np.zeros(shape))), None
        fresh = keys.normal(Stream.LOSS, self.kind, self.occ, epochs, 0)
        if not self.stateful:
            return LayerOutput(reach_m=self.reach(self.sigma * fresh)), None
        if carry is None:
            first = keys.normal(Stream.LOSS, self.kind, self.occ, np.zeros(1, np.int64), 1)
            carry = self.sigma * first[:, 0]
        x = run_ar1(math.sqrt(1.0 - self.c**2) * self.sigma, self.c, fresh, carry)
        return LayerOutput(reach_m=self.reach(x)), x[:, -1]

    def reach(self, shadowing_db: Floats) -> Floats:
        """The longest link that delivers under shadowing ``X`` [dB]: ``m(d) ≥ X`` ⟺
        ``d ≤ d0 10^(M / 10n)``, ``M = P_t − PL(d0) − sensitivity − X``; −inf when ``M < 0``."""
        s = self.spec
        budget = s.tx_power_dbm - s.path_loss_d0_db - s.sensitivity_dbm - shadowing_db
        reach = s.d0_m * np.power(10.0, budget / (10.0 * s.n))
        return np.asarray(np.where(budget >= 0.0, reach, -np.inf), dtype=np.float64)

    def margin_db(self, distance_m: Floats) -> Floats:
        """``m(d)`` [dB]: received power above the threshold without shadowing."""
        s = self.spec
        d = np.maximum(np.asarray(distance_m, dtype=np.float64), s.d0_m)
        path_loss = s.path_loss_d0_db + 10.0 * s.n * np.log10(d / s.d0_m)
        return np.asarray(s.tx_power_dbm - path_loss - s.sensitivity_dbm, dtype=np.float64)

    def delivery_at(self, distance_m: Floats) -> Floats:
        m = self.margin_db(distance_m)
        if self.sigma == 0.0:
            return np.asarray(m >= 0.0, dtype=np.float64)
        return np.asarray(ndtr(m / self.sigma), dtype=np.float64)


LAYER = LogDistanceLayer

__all__ = ["LAYER", "LogDistanceLayer"]
