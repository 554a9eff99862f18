"""Scenario variants under loss: every formation link under one model at a mean loss rate.

Bernoulli ``p_loss = ρ``; Gilbert–Elliott with loss only in the bad state and mean burst ``β``
epochs, at the same long-run rate ``ρ`` (docs: ``testbed.experiments.sweep``).
"""

from __future__ import annotations

from typing import Any

from formation.errors import UnknownLossModel
from formation.scenario import Scenario

LOSS_MODELS = ("bernoulli", "gilbert_elliott")


def gilbert_elliott_at(rate: float, burst_epochs: float) -> dict[str, float]:
    """Gilbert–Elliott parameters with long-run loss ``rate`` and mean burst ``burst_epochs``."""
    if rate <= 0.0:
        return {"p": 0.0, "r": 1.0 / burst_epochs}
    if rate >= 1.0:
        return {"p": 1.0, "r": 0.0}
    r = 1.0 / burst_epochs
    p = rate * r / (1.0 - rate)
    if p > 1.0:
        p, r = 1.0, (1.0 - rate) / rate
    return {"p": p, "r": r}


def with_loss(scenario: Scenario, model: str, rate: float, burst_epochs: float = 4.0) -> Scenario:
    """``scenario`` with every formation link under ``model`` at mean loss ``rate``."""
    if model == "bernoulli":
        spec: dict[str, Any] = {"model": "bernoulli", "p_loss": rate}
    elif model == "gilbert_elliott":
        spec = {
            "model": "gilbert_elliott",
            **gilbert_elliott_at(rate, burst_epochs),
            "1-h": 1.0,
            "1-k": 0.0,
        }
    else:
        raise UnknownLossModel(model, LOSS_MODELS)
    net = scenario.network.model_dump(by_alias=True)
    net.update(formation_default=[spec], links=[])
    return scenario.with_overrides(network=net)


__all__ = ["LOSS_MODELS", "gilbert_elliott_at", "with_loss"]
