"""``outage``: the link is down in ``[start, end)`` epochs, repeating every ``every`` epochs.

With ``start_s``/``end_s`` it is a realtime window in seconds instead: its epoch
fields are ignored, and ``decide`` needs ``time_s`` (seconds since the run
started); such a window does not repeat. Long-run loss: ``(end - start) /
every`` when it repeats, 0 for a one-off window, 1 when it never ends.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from formation.linkmodels import Outage
from netem.links.layer import Bools, Floats, Ints, Keys, Layer, LayerOutput


class OutageLayer(Layer[Outage]):
    state_names = ("", "down")

    def __init__(self, spec: Outage, occurrence: int) -> None:
        super().__init__(spec, occurrence)
        self.timed = spec.start_s is not None or spec.end_s is not None
        self.start_s = spec.start_s if spec.start_s is not None else 0.0
        self.end_s = spec.end_s if spec.end_s is not None else math.inf

    def drops_at(self, time_s: Floats | float) -> Bools:
        return np.asarray((time_s >= self.start_s) & (time_s < self.end_s), dtype=np.bool_)

    def timing(self) -> str:
        o = self.spec
        return f"outage is given in seconds (start_s = {o.start_s}, end_s = {o.end_s})"

    def run(
        self, keys: Keys, epochs: Ints, carry: npt.NDArray[Any] | None
    ) -> tuple[LayerOutput, Any]:
        o = self.spec
        if self.timed:  # applied later from the packet times
            down = np.zeros(epochs.shape, dtype=np.bool_)
        elif o.end is None:
            down = epochs >= o.start
        elif o.every is None:
            down = (epochs >= o.start) & (epochs < o.end)
        else:
            down = (epochs >= o.start) & ((epochs - o.start) % o.every < o.end - o.start)
        full = np.broadcast_to(down, (keys.n_links, epochs.shape[0]))
        return LayerOutput(drop=full, state=full.astype(np.int8)), None

    def loss_rate(self) -> float:
        o = self.spec
        if self.timed:
            return 1.0 if o.end_s is None else 0.0
        if o.end is None:
            return 1.0
        return (o.end - o.start) / o.every if o.every is not None else 0.0


LAYER = OutageLayer

__all__ = ["LAYER", "OutageLayer"]
