"""``gilbert_elliott``: two-state Markov loss (tc ``loss gemodel p r 1-h 1-k``).

The packet of epoch ``k`` is lost with the loss probability of the state the
chain is in when it arrives (``1-k`` good, ``1-h`` bad), then the chain moves
(``p`` good→bad, ``r`` bad→good); it starts good. ``state`` reports that entry
state. Long run: ``π_bad = p / (p + r)``, loss ``π_bad (1-h) + π_good (1-k)``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from formation.keyed_random import Stream
from formation.linkmodels import GilbertElliott
from netem.links.chains import COMPILED_FROM, run_chain
from netem.links.layer import Floats, Ints, Keys, Layer, LayerOutput


class GilbertElliottLayer(Layer[GilbertElliott]):
    stateful = True
    state_names = ("good", "bad")

    def __init__(self, spec: GilbertElliott, occurrence: int) -> None:
        super().__init__(spec, occurrence)
        self.loss = np.array([spec.one_minus_k, spec.one_minus_h])

    def run(
        self, keys: Keys, epochs: Ints, carry: npt.NDArray[Any] | None
    ) -> tuple[LayerOutput, Any]:
        g = self.spec
        u_move = keys.uniform(Stream.LOSS, self.kind, self.occ, epochs, 0)
        u_loss = keys.uniform(Stream.LOSS, self.kind, self.occ, epochs, 1)
        s0 = np.zeros(keys.n_links, np.int64) if carry is None else carry
        if u_move.size >= COMPILED_FROM:  # the simulator's many links: one compiled pass
            from netem.links.compiled_chain import gilbert_elliott_chains

            entry = np.empty(u_move.shape, dtype=np.int8)
            drop = np.empty(u_move.shape, dtype=np.bool_)
            last = gilbert_elliott_chains(
                u_move, u_loss, g.p, g.r, self.loss, s0.astype(np.int64), entry, drop
            )
            return LayerOutput(drop=drop, state=entry), last
        # next state from good (0): bad iff u < p; from bad (1): good iff u < r
        table = np.stack([u_move < g.p, u_move >= g.r], axis=-1).astype(np.int64)
        post = run_chain(table, s0)
        entry = np.concatenate([s0[:, None], post[:, :-1]], axis=1)
        return LayerOutput(drop=u_loss < self.loss[entry], state=entry.astype(np.int8)), post[:, -1]

    def loss_chain(self) -> tuple[Floats, Floats]:
        g = self.spec
        p, r = g.p, g.r
        return np.array([[1 - p, p], [r, 1 - r]]), np.array([g.one_minus_k, g.one_minus_h])


LAYER = GilbertElliottLayer

__all__ = ["LAYER", "GilbertElliottLayer"]
