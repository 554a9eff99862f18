"""``reorder``: an epoch's packets skip all delay of the stack w.p. ``p`` (tc ``reorder P gap N``).

Once ``N - 1`` epochs have passed since the last reordered one, each epoch's
packets are reordered with probability ``P`` (``gap = 1``: every epoch
independently; ``P = 1``: every ``N``-th epoch). Unlike tc, the counter counts
epochs, dropped or not, so layers stay independent.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from formation.keyed_random import Stream
from formation.linkmodels import Reorder
from netem.links.chains import run_chain
from netem.links.layer import Floats, Ints, Keys, Layer, LayerOutput, lossless


class ReorderLayer(Layer[Reorder]):
    def __init__(self, spec: Reorder, occurrence: int) -> None:
        super().__init__(spec, occurrence)
        self.p, self.gap = spec.p, spec.gap
        self.stateful = self.gap > 1

    def run(
        self, keys: Keys, epochs: Ints, carry: npt.NDArray[Any] | None
    ) -> tuple[LayerOutput, Any]:
        hit = keys.uniform(Stream.REORDER, self.kind, self.occ, epochs) < self.p
        if not self.stateful:
            return LayerOutput(reorder=hit), None
        top = self.gap - 1  # the counter (epochs since the last reordered one) saturates here
        count = np.zeros(keys.n_links, np.int64) if carry is None else np.minimum(carry, top)
        # state = counter; from `top` a hit resets to 0, anything else counts up to `top`
        up = np.minimum(np.arange(self.gap) + 1, top)
        table = np.broadcast_to(up, (*hit.shape, self.gap)).copy()
        table[..., top] = np.where(hit, 0, top)
        post = run_chain(table, count)
        entry = np.concatenate([count[:, None], post[:, :-1]], axis=1)
        return LayerOutput(reorder=(entry == top) & hit), post[:, -1]

    def loss_chain(self) -> tuple[Floats, Floats]:
        return lossless()


LAYER = ReorderLayer

__all__ = ["LAYER", "ReorderLayer"]
