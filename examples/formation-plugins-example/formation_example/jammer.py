"""``jammer``: every packet on the chosen links is lost during a schedule.

A jammer switched on at epoch ``start`` for ``length`` epochs, again every ``every`` epochs
(never again when ``every`` is absent), on the directed links ``links`` (``[src, dst]``; 0 is
the leader, so ``[3, 0]`` is agent 3's reports). Deterministic: it needs no keyed draws, but
a layer that does draws them from ``keys`` by ``(seed, link, epoch)``, as netem's own do.
"""

from __future__ import annotations

from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import Field, model_validator

from formation.linkmodels import Spec
from netem import Keys, Layer, LayerOutput


class Jammer(Spec):
    """Every packet on ``links`` lost for ``length`` epochs from ``start``, again each ``every``.

    The spec is what a scenario writes: ``{ model = "jammer", links = [[1, 2]], start = 10 }``.
    """

    layer: ClassVar[str] = "formation_example.jammer:JammerLayer"
    model: Literal["jammer"] = "jammer"
    links: tuple[tuple[int, int], ...] = Field(min_length=1)
    start: int = Field(0, ge=0)
    length: int = Field(1, ge=1)
    every: int | None = Field(None, gt=0)

    @model_validator(mode="after")
    def _fits(self) -> Jammer:
        if self.every is not None and self.length > self.every:
            raise ValueError(f"length = {self.length} is longer than every = {self.every}")
        return self


class JammerLayer(Layer[Jammer]):
    """The behaviour: drops ``(L, n)`` for ``L`` links over the epochs ``(n,)`` asked."""

    state_names = ("", "jammed")

    def run(self, keys: Keys, epochs: np.ndarray, carry: Any) -> tuple[LayerOutput, Any]:
        j = self.spec
        since = epochs - j.start
        on = since >= 0
        on &= (since % j.every if j.every is not None else since) < j.length  # (n,)
        jammed = np.zeros(keys.n_links, dtype=bool)  # (L,)
        for src, dst in j.links:
            jammed |= (keys.src[:, 0] == src) & (keys.dst[:, 0] == dst)
        drop = jammed[:, None] & on[None, :]
        return LayerOutput(drop=drop, state=drop.astype(np.int8)), None

    def loss_rate(self) -> float:
        """Long-run share of epochs jammed, on a jammed link."""
        j = self.spec
        return j.length / j.every if j.every is not None else 0.0
