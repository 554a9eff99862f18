"""Plug-ins that go wrong, each in its own way, for the tests of how the testbed refuses them,
and a few that test what a plug-in may rely on (its own defaults, the epoch).

On ``PYTHONPATH`` (the tests put ``tests/data/plugins`` there), a scenario names them as
``"bad_plugins:NAME"``.
"""

from __future__ import annotations

from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from formation.linkmodels import Spec
from formation.plugin_api import ControlInputs, ControlLaw, Fill, LossStrategy, StrategyInputs
from netem import Keys, Layer, LayerOutput


class FailParams(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    at_epoch: int = Field(6, ge=4)  # after the load-time probe (epoch 3)
    how: Literal["raise", "nan", "shape"] = "nan"
    agent: int = 3  # the receiver whose link goes wrong ("nan")


def _hold(x: StrategyInputs) -> Fill:
    have = x.lost & x.has_last
    return Fill(x.last, have, np.zeros_like(have), x.state, x.has_state)


def fails_later(inputs: StrategyInputs, params: FailParams) -> Fill:
    """``hold`` until ``at_epoch``, then the failure ``how`` (for every call from then on)."""
    fill = _hold(inputs)
    if inputs.epoch < params.at_epoch:
        return fill
    if params.how == "raise":
        raise RuntimeError("the user's strategy broke")
    if params.how == "shape":
        return Fill(fill.values[:, :1], fill.have, fill.fallback, fill.state, fill.has_state)
    values = fill.values.copy()
    values[:] = np.nan  # every row; the check names the receivers of the links it fills
    return Fill(values, inputs.lost, fill.fallback, fill.state, fill.has_state)


FAILS_LATER = LossStrategy(fails_later, params=FailParams)


def wrong_shape(inputs: StrategyInputs, params: Any) -> Fill:
    fill = _hold(inputs)
    return Fill(fill.values[:1], fill.have, fill.fallback, fill.state, fill.has_state)


WRONG_SHAPE = LossStrategy(wrong_shape)  # caught by the probe, at load


def one_argument(inputs: StrategyInputs) -> Fill:
    return _hold(inputs)


WRONG_SIGNATURE = LossStrategy(one_argument)  # type: ignore[arg-type]

NOT_A_STRATEGY = object()


def only_single(inputs: ControlInputs, params: Any) -> np.ndarray:
    return np.zeros((inputs.n, inputs.relative.shape[1]))


SINGLE_ONLY = ControlLaw(only_single, dynamics=("single",))


def infinite(inputs: ControlInputs, params: Any) -> np.ndarray:
    return np.full((inputs.n, inputs.relative.shape[1]), np.inf)


INFINITE = ControlLaw(infinite)  # caught by the probe, at load


class Explodes(Spec):
    """A link model whose layer raises from ``at_epoch`` on (after the load-time probe's 8)."""

    layer: ClassVar[str] = "bad_plugins:ExplodingLayer"
    model: Literal["explodes"] = "explodes"
    at_epoch: int = Field(12, ge=8)


class ExplodingLayer(Layer[Explodes]):
    def run(self, keys: Keys, epochs: np.ndarray, carry: Any) -> tuple[LayerOutput, Any]:
        if (epochs >= self.spec.at_epoch).any():
            raise ValueError("the user's layer broke")
        return LayerOutput(drop=np.zeros((keys.n_links, epochs.shape[0]), dtype=bool)), None


class OwnAlpha(BaseModel):
    """A parameter named as blend's α, with a default of its own."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    alpha: float = Field(0.9, gt=0.0, le=1.0)


def scaled_hold(inputs: StrategyInputs, params: OwnAlpha) -> Fill:
    fill = _hold(inputs)
    return fill._replace(values=params.alpha * fill.values)


OWN_ALPHA = LossStrategy(scaled_hold, params=OwnAlpha)  # not shadowed by blend's alpha


def late(inputs: ControlInputs, params: Any) -> np.ndarray:
    """Still until epoch 5, then the displacement law: a controller that varies in time."""
    x = inputs
    u = np.zeros((x.n, x.relative.shape[1]))
    if x.epoch < 5:
        return u
    np.add.at(u, x.receivers, np.where(x.used[:, None], x.relative - x.desired, 0.0))
    return -x.epsilon * u


LATE = ControlLaw(late)


class NanDelay(Spec):
    """A link model whose delay is NaN from ``at_epoch`` on."""

    layer: ClassVar[str] = "bad_plugins:NanDelayLayer"
    model: Literal["nan_delay"] = "nan_delay"
    at_epoch: int = Field(12, ge=8)


class NanDelayLayer(Layer[NanDelay]):
    def run(self, keys: Keys, epochs: np.ndarray, carry: Any) -> tuple[LayerOutput, Any]:
        shape = (keys.n_links, epochs.shape[0])
        delay_ms = np.where(epochs >= self.spec.at_epoch, np.nan, 0.0)[None, :].repeat(shape[0], 0)
        zeros = np.zeros(shape, dtype=np.int64)
        return LayerOutput(delay_epochs=zeros, delay_ms=delay_ms), None
