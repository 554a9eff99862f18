"""``down``: the link drops every packet; its state is ``"down"``."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from formation.linkmodels import Down
from netem.links.layer import Floats, Ints, Keys, Layer, LayerOutput


class DownLayer(Layer[Down]):
    state_names = ("", "down")

    def run(
        self, keys: Keys, epochs: Ints, carry: npt.NDArray[Any] | None
    ) -> tuple[LayerOutput, Any]:
        ones = np.ones((keys.n_links, epochs.shape[0]), dtype=np.bool_)
        return LayerOutput(drop=ones, state=ones.astype(np.int8)), None

    def loss_chain(self) -> tuple[Floats, Floats]:
        return np.ones((1, 1)), np.ones(1)


LAYER = DownLayer

__all__ = ["LAYER", "DownLayer"]
