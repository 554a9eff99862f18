"""``markov4``: tc netem's four-state loss (``loss state p13 p31 p32 p23 p14``).

States are numbered as the parameter names number them (Salsano et al.'s GI
model; in Linux ``loss_4state`` 1 = ``TX_IN_GAP_PERIOD``, 2 =
``TX_IN_BURST_PERIOD``, 3 = ``LOST_IN_BURST_PERIOD``, 4 = ``LOST_IN_GAP_PERIOD``,
whatever the kernel's enum values): 1 good reception, 2 reception inside a
burst, 3 loss inside a burst, 4 isolated loss. Per epoch the chain first moves
(1→4 w.p. ``p14``, 1→3 w.p. ``p13``; 2→3 w.p. ``p23``; 3→2 w.p. ``p32``, 3→1 w.p.
``p31``; 4→1 always), then the packet is lost iff the new state is 3 or 4. The
chain starts in 1. Long run (``D`` the sum of the four): ``π1 = p31 p23 / D``,
``π2 = p13 p32 / D``, ``π3 = p13 p23 / D``, ``π4 = p14 p31 p23 / D``; loss ``π3 + π4``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from formation.keyed_random import Stream
from formation.linkmodels import Markov4
from netem.links.chains import run_chain
from netem.links.layer import Floats, Ints, Keys, Layer, LayerOutput


class Markov4Layer(Layer[Markov4]):
    stateful = True
    state_names = ("", "1", "2", "3", "4")

    def run(
        self, keys: Keys, epochs: Ints, carry: npt.NDArray[Any] | None
    ) -> tuple[LayerOutput, Any]:
        m = self.spec
        u = keys.uniform(Stream.LOSS, self.kind, self.occ, epochs)
        s0 = np.zeros(keys.n_links, np.int64) if carry is None else carry
        # states 0..3 stand for 1..4; comparisons in the order of Linux loss_4state
        from1 = np.where(u < m.p14, 3, np.where(u < m.p14 + m.p13, 2, 0))
        from2 = np.where(u < m.p23, 2, 1)
        from3 = np.where(u < m.p32, 1, np.where(u < m.p32 + m.p31, 0, 2))
        table = np.stack([from1, from2, from3, np.zeros_like(from1)], axis=-1).astype(np.int64)
        post = run_chain(table, s0)
        return LayerOutput(drop=post >= 2, state=(post + 1).astype(np.int8)), post[:, -1]

    def problem(self) -> str | None:
        m = self.spec  # the spec checks this too; a model_construct'ed one may not have been
        if m.p13 + m.p14 > 1.0:
            return f"markov4 has p13 + p14 = {m.p13 + m.p14:g}; expected <= 1"
        if m.p31 + m.p32 > 1.0:
            return f"markov4 has p31 + p32 = {m.p31 + m.p32:g}; expected <= 1"
        return None

    def loss_chain(self) -> tuple[Floats, Floats]:
        s = self.spec
        t = np.array(
            [
                [1 - s.p13 - s.p14, 0.0, s.p13, s.p14],
                [0.0, 1 - s.p23, s.p23, 0.0],
                [s.p31, s.p32, 1 - s.p31 - s.p32, 0.0],
                [1.0, 0.0, 0.0, 0.0],
            ]
        )
        return t, np.array([0.0, 0.0, 1.0, 1.0])


LAYER = Markov4Layer

__all__ = ["LAYER", "Markov4Layer"]
