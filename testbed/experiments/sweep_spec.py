"""What a ``formation sweep`` covers (:class:`SweepSpec`) and how its grids are written.

Light on purpose: ``formation sweep --help`` and the argument checks import it without numpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from formation.errors import SweepError

if TYPE_CHECKING:
    from formation.scenario import Scenario, StrategyName

Key = tuple[str, str, str, str, int, int]  # topology, model, loss, strategy, seed, epochs


def value_grid(text: str, flag: str = "--loss") -> tuple[float, ...]:
    """``"0:1:0.05"`` → 0, 0.05, …, 1 (both ends); ``"0.1,0.3"`` → those values, sorted."""
    try:
        if ":" in text:
            start, stop, step = (float(v) for v in text.split(":"))
            if step <= 0:
                raise SweepError(f"{flag} {text!r}", f"step = {step:g}; expected > 0")
            count = math.floor((stop - start) / step + 1e-9) + 1
            values = [round(start + i * step, 10) for i in range(count)]
        else:
            values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise SweepError(
            f"{flag} {text!r}", "expected START:STOP:STEP or a comma list of values"
        ) from None
    if not values or not all(math.isfinite(v) for v in values):
        raise SweepError(f"{flag} {text!r}", f"expected finite values, got {values or 'none'}")
    return tuple(sorted(set(values)))


def loss_grid(text: str) -> tuple[float, ...]:
    """:func:`value_grid` of loss rates, each in [0, 1]."""
    values = value_grid(text)
    bad = [v for v in values if not 0.0 <= v <= 1.0]
    if bad:
        raise SweepError(f"--loss {text!r}", f"rates must be in [0, 1], got {bad}")
    return values


def loss_label(rate: float) -> str:
    """The loss rate as written in the CSV and the tables (e.g. ``0.05``)."""
    return f"{rate:.6g}"


@dataclass(frozen=True)
class SweepSpec:
    """What a sweep covers; every cell is ``(topology, model, loss, strategy, seed)``."""

    topologies: tuple[tuple[str, Scenario], ...]
    losses: tuple[float, ...]
    strategies: tuple[StrategyName, ...]
    seeds: tuple[int, ...]
    models: tuple[str, ...] = ("bernoulli",)
    epochs: int = 200
    threshold_m: float = 0.05
    burst_epochs: float = 4.0
    seeds_per_chunk: int = 10

    def keys(self) -> list[Key]:
        """Every cell, in the canonical order of the CSV."""
        return [
            (t, m, loss_label(p), s, seed, self.epochs)
            for t, _ in self.topologies
            for m in self.models
            for p in self.losses
            for s in self.strategies
            for seed in self.seeds
        ]


__all__ = ["Key", "SweepSpec", "loss_grid", "loss_label", "value_grid"]
