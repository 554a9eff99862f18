"""Scenario variants under loss: every formation link under one model at a mean loss rate,
or the scenario's own link models with one parameter set.

Bernoulli ``p_loss = ρ``; Gilbert–Elliott with loss only in the bad state and mean burst ``β``
epochs, at the same long-run rate ``ρ`` (docs: ``testbed.experiments.sweep``). A variant named
``tag.param`` (``jammer.length``) keeps the scenario's network and sets ``param`` of every
link model ``tag`` in it, a plug-in's as a built-in's.
"""

from __future__ import annotations

from typing import Any

from formation.errors import SweepError, UnknownLossModel
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


def is_parameter(model: str) -> bool:
    """A variant that sets a parameter of the scenario's own link models (``tag.param``)."""
    return "." in model


def with_parameter(scenario: Scenario, model: str, value: float) -> Scenario:
    """``scenario`` with ``param`` = ``value`` in every link model ``tag`` of its network
    (``model`` = ``tag.param``); its other models and links as they are."""
    tag, _, param = model.rpartition(".")
    net = scenario.network.model_dump(by_alias=True)
    found = 0

    def each(specs: list[dict[str, Any]]) -> None:
        nonlocal found
        for spec in specs:
            if spec["model"] == tag:
                spec[param] = value
                found += 1

    each(net["formation_default"])
    each(net["control_default"])
    for link in (*net["links"], *net["control"]):
        each(link["models"])
    if not found:
        used = sorted({spec.model for _, stack in scenario.model_stacks() for spec in stack})
        raise SweepError(
            f"--vary {model}",
            f"the scenario {scenario.name!r} has no link model {tag!r} "
            f"(it has: {', '.join(used) or 'none'})",
        )
    return scenario.with_overrides(network=net)


def with_loss(scenario: Scenario, model: str, rate: float, burst_epochs: float = 4.0) -> Scenario:
    """``scenario`` with every formation link under ``model`` at mean loss ``rate``, or with
    parameter ``model`` = ``tag.param`` set to ``rate`` (:func:`with_parameter`)."""
    if is_parameter(model):
        return with_parameter(scenario, model, rate)
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


__all__ = ["LOSS_MODELS", "gilbert_elliott_at", "is_parameter", "with_loss", "with_parameter"]
