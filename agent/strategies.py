"""Loss strategies (docs/model.md §6): the value ``x̃_j[k]`` an agent uses for a lost packet.

Vectorised over a batch of directed in-links ``j → i``. ``LinkMemory`` is what a
receiver remembers of each in-link; :func:`substitute` is pure and returns the
new memory rather than changing the old one. The chapter's strategies are plug-ins
(``formation.plugin_api.LossStrategy``), registered by entry point like a user's:
``ZERO``, ``HOLD``, ``ESTIMATE``, ``BLEND`` and ``DROP`` below.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt
from pydantic import BaseModel, ConfigDict, Field

from formation.plugin_api import Fill, LossStrategy, StrategyInputs, fill_checked, loss_strategy

Array = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class LinkMemory:
    """Per in-link memory: last received value and the strategy's own state.

    last : (L, d) last received ``x_j`` [m]; ``last_epoch`` (L,) the epoch it was sent (−1: none)
    state : (L, w) the strategy's state (``blend``: ``b_j[k−1]`` [m]); ``has_state`` (L,)
    """

    last: Array
    last_epoch: npt.NDArray[np.int64]
    state: Array
    has_state: Mask

    @classmethod
    def empty(cls, n_links: int, d: int, width: int = 0) -> LinkMemory:
        """No link remembers anything; ``width`` is the strategy's state per link."""
        return cls(
            last=np.zeros((n_links, d)),
            last_epoch=np.full(n_links, -1, dtype=np.int64),
            state=np.zeros((n_links, width)),
            has_state=np.zeros(n_links, dtype=bool),
        )

    def take(self, rows: npt.NDArray[np.int64]) -> LinkMemory:
        """The memory of the links ``rows`` only."""
        return LinkMemory(
            self.last[rows], self.last_epoch[rows], self.state[rows], self.has_state[rows]
        )

    def put(self, rows: npt.NDArray[np.int64], part: LinkMemory) -> LinkMemory:
        """This memory with the links ``rows`` replaced by ``part`` (the others kept)."""
        return LinkMemory(
            _scatter(self.last, rows, part.last),
            _scatter(self.last_epoch, rows, part.last_epoch),
            _scatter(self.state, rows, part.state),
            _scatter(self.has_state, rows, part.has_state),
        )

    def forget(self, rows: Mask) -> LinkMemory:
        """The links ``rows`` (L,) remember nothing: a receiver that (re)starts (issue 20)."""
        keep = ~rows
        return LinkMemory(
            self.last * keep[:, None],
            np.where(keep, self.last_epoch, -1),
            self.state * keep[:, None],
            self.has_state & keep,
        )

    @property
    def has_last(self) -> Mask:
        return self.last_epoch >= 0

    def receive_late(
        self, values: Array, sent_epoch: npt.NDArray[np.int64], mask: Mask
    ) -> LinkMemory:
        """A delayed packet arrives: it becomes the held value if newer than what is held."""
        newer = mask & (sent_epoch > self.last_epoch)
        return replace(
            self,
            last=np.where(newer[:, None], values, self.last),
            last_epoch=np.where(newer, sent_epoch, self.last_epoch),
        )


@dataclass(frozen=True)
class Substitution:
    """What the controller uses for each in-link this epoch.

    values : (L, d) ``x̃_j`` for lost links (received ``x_j`` where arrived) [m]
    used : (L,) whether the link's term enters the consensus sum
    substituted : (L,) lost and given a value (the substitution error is measured here)
    fallback : (L,) the strategy fell back (``estimate``/``blend``: no estimate, so ``hold``)
    """

    values: Array
    used: Mask
    substituted: Mask
    fallback: Mask

    def spread(self, rows: npt.NDArray[np.int64], size: int) -> Substitution:
        """This substitution of the links ``rows`` over all ``size`` links (the others: none)."""
        none = np.zeros(size, dtype=bool)
        return Substitution(
            _scatter(np.zeros((size, self.values.shape[1])), rows, self.values),
            _scatter(none, rows, self.used),
            _scatter(none, rows, self.substituted),
            _scatter(none, rows, self.fallback),
        )


def _scatter(
    full: npt.NDArray[Any], rows: npt.NDArray[np.int64], part: npt.NDArray[Any]
) -> npt.NDArray[Any]:
    out = full.copy()
    out[rows] = part
    return out


def substitute(
    strategy: str,
    params: Any,
    epoch: int,
    arrived: Mask,
    received: Array,
    memory: LinkMemory,
    estimate: Array,
    has_estimate: Mask,
    v_ref_prev: Array,
    period_s: float,
    receivers: npt.NDArray[np.int64],
) -> tuple[Substitution, LinkMemory]:
    """Fill lost coordination variables by the loss strategy plug-in ``strategy``.

    Parameters
    ----------
    strategy : a registered strategy's name (``zero``, ``hold``, ``estimate``, ``blend``, ``drop``,
        or a user's), or ``"package.module:name"``; ``params`` its validated parameters
    epoch : the current epoch ``k`` (stored with received values)
    arrived : (L,) the epoch-``k`` packet of the link arrived in time
    received : (L, d) its ``x_j[k]`` where arrived (ignored elsewhere) [m]
    memory : the links' memory from epoch ``k − 1``
    estimate : (L, d) the leader's ``x̂_j[k]`` [m]; ``has_estimate`` (L,) where it exists
    v_ref_prev : (d,) or (L, d) ``v_ref[k − 1]`` as each receiver knows it [m/s] (zero at k = 0)
    period_s : T [s]
    receivers : (L,) the links' receiving agent ids (named when the plug-in fails)

    Returns
    -------
    the substitution and the memory for epoch ``k + 1``
    """
    plugin = loss_strategy(strategy)
    lost = ~arrived
    inputs = StrategyInputs(
        epoch=epoch,
        arrived=arrived,
        received=received,
        last=memory.last,
        last_epoch=memory.last_epoch,
        estimate=estimate,
        has_estimate=has_estimate,
        v_ref_prev=v_ref_prev
        if v_ref_prev.ndim == 2
        else np.broadcast_to(v_ref_prev, received.shape),
        period_s=period_s,
        state=memory.state,
        has_state=memory.has_state,
        lost=lost,
        has_last=memory.last_epoch >= 0,
    )
    fill = fill_checked(strategy, plugin, inputs, params, receivers)
    have = fill.have & lost
    values = np.where(arrived[:, None], received, 0.0)
    values = np.where(have[:, None], fill.values, values)
    new_memory = LinkMemory(
        last=np.where(arrived[:, None], received, memory.last),
        last_epoch=np.where(arrived, epoch, memory.last_epoch),
        state=fill.state,
        has_state=fill.has_state,
    )
    substitution = Substitution(
        values=values, used=arrived | have, substituted=have, fallback=fill.fallback & lost
    )
    return substitution, new_memory


# ----------------------------------------------------------------------------- the chapter's strategies


def _none(x: StrategyInputs) -> Mask:
    return np.zeros_like(x.arrived)


def _zero(x: StrategyInputs, params: Any) -> Fill:
    """``x̃ = 0``, the origin."""
    return Fill(np.zeros_like(x.received), x.lost, _none(x), x.state, x.has_state)


def _hold(x: StrategyInputs, params: Any) -> Fill:
    """The last value received (nothing where none was)."""
    have = x.lost & x.has_last
    return Fill(x.last, have, _none(x), x.state, x.has_state)


def _estimate(x: StrategyInputs, params: Any) -> Fill:
    """The leader's estimate ``x̂_j[k]``; without one, ``hold``."""
    est = x.lost & x.has_estimate
    fallback = x.lost & ~x.has_estimate
    held = fallback & x.has_last
    values = np.where(est[:, None], x.estimate, x.last)
    return Fill(values, est | held, fallback, x.state, x.has_state)


class BlendParams(BaseModel):
    """``blend``'s filter factor α ∈ (0, 1]."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    alpha: float = Field(0.5, gt=0.0, le=1.0)


def _blend(x: StrategyInputs, params: BlendParams) -> Fill:
    """``b[k] = α x̂ + (1 − α)(b[k−1] + T v_ref[k−1])``; without an estimate, ``hold``."""
    alpha = params.alpha
    blend, has_blend = x.state, x.has_state
    predicted = blend + x.period_s * x.v_ref_prev
    est = x.lost & x.has_estimate
    # A filter with no past starts at the estimate.
    filtered = np.where(
        has_blend[:, None], alpha * x.estimate + (1.0 - alpha) * predicted, x.estimate
    )
    fallback = x.lost & ~x.has_estimate
    held = fallback & x.has_last
    values = np.where(est[:, None], filtered, x.last)
    # Without an estimate the filter only predicts; the value used is the held one (docs/model.md §6).
    blend = np.where(est[:, None], filtered, np.where(fallback[:, None], predicted, blend))
    # A packet that arrives restarts the filter from the received value.
    state = np.where(x.arrived[:, None], x.received, blend)
    return Fill(values, est | held, fallback, state, has_blend | est | x.arrived)


def _drop(x: StrategyInputs, params: Any) -> Fill:
    """The lost neighbour's term is left out of the consensus sum (the baseline)."""
    return Fill(np.zeros_like(x.received), _none(x), _none(x), x.state, x.has_state)


def _dimension(d: int) -> int:
    return d


ZERO = LossStrategy(_zero, description="x̃ = 0, the origin (docs/model.md §6)")
HOLD = LossStrategy(_hold, description="the last value received")
ESTIMATE = LossStrategy(_estimate, description="the leader's estimate; without one, hold")
BLEND = LossStrategy(
    _blend,
    params=BlendParams,
    state_width=_dimension,
    description="α x̂ + (1 − α)(b[k−1] + T v_ref[k−1]); without an estimate, hold",
)
DROP = LossStrategy(_drop, description="the term is left out (the baseline)")


def state_width(strategy: str, dimension: int) -> int:
    """Floats of state strategy ``strategy`` keeps per link."""
    return int(loss_strategy(strategy).state_width(dimension))
