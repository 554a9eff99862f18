"""``saturated``: the displacement law with each agent's step no longer than ``max_step_m``.

``u_i = −ε Σ_j [z̃_ij − (d0_i − d0_j)]`` as the displacement law, then scaled by
``min(1, max_step_m / ||u_i||)``: a robot cannot move further than its actuators allow in
one epoch, so a large error (after a long loss) is closed at a bounded speed.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from pydantic import BaseModel, ConfigDict, Field

from formation.plugin_api import ControlInputs, ControlLaw


class SaturatedParams(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    max_step_m: float = Field(0.2, gt=0.0)  # [m] per epoch


def saturated(inputs: ControlInputs, params: SaturatedParams) -> npt.NDArray[np.float64]:
    """Returns the ``(n, d)`` position increment [m]."""
    x = inputs
    terms = np.where(x.used[:, None], x.relative - x.desired, 0.0)  # (L, d)
    u = np.zeros((x.n, x.relative.shape[1]))
    np.add.at(u, x.receivers, terms)
    u *= -x.epsilon
    norm = np.linalg.norm(u, axis=1)  # (n,)
    scale = np.minimum(1.0, params.max_step_m / np.maximum(norm, 1e-300))
    out: npt.NDArray[np.float64] = u * scale[:, None]
    return out


SATURATED = ControlLaw(
    saturated,
    params=SaturatedParams,
    description="the displacement law, each agent's step clipped to max_step_m",
)
