"""``extrapolate``: a lost ``x_j[k]`` is the last one received, moved by ``v_ref`` since.

``x̃_j[k] = x_j[s] + T (k − s) v_ref[k − 1]`` where ``s`` is the epoch of the last packet
received from ``j``, and ``k − s`` is capped at ``horizon_epochs`` (a neighbour lost for long
is not pushed on for ever). Without anything received yet, the leader's estimate if there
is one (counted as a fallback), else the term is left out. The formation moves with the
reference, so a held value falls behind by ``T v_ref`` an epoch; this strategy does not.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from formation.plugin_api import Fill, LossStrategy, StrategyInputs


class ExtrapolateParams(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    horizon_epochs: int = Field(20, ge=1)  # at most this many epochs ahead of the last packet


def extrapolate(inputs: StrategyInputs, params: ExtrapolateParams) -> Fill:
    """Vectorised over the in-links: every array is ``(L,)`` or ``(L, d)``."""
    x = inputs
    ahead = np.minimum(x.epoch - x.last_epoch, params.horizon_epochs)  # (L,) epochs since
    moved = x.last + (x.period_s * ahead)[:, None] * x.v_ref_prev  # (L, d) [m]
    held = x.lost & x.has_last
    fallback = x.lost & ~x.has_last & x.has_estimate
    values = np.where(held[:, None], moved, x.estimate)
    return Fill(values, held | fallback, fallback, x.state, x.has_state)


EXTRAPOLATE = LossStrategy(
    extrapolate,
    params=ExtrapolateParams,
    description="the last value received, moved on by T v_ref per epoch since (capped)",
)
