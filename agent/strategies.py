"""Loss strategies (docs/model.md §6): the value ``x̃_j[k]`` an agent uses for a lost packet.

Vectorised over a batch of directed in-links ``j → i``. ``LinkMemory`` is what a
receiver remembers of each in-link; :func:`substitute` is pure and returns the
new memory rather than changing the old one.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from formation.scenario import StrategyName

Array = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class LinkMemory:
    """Per in-link memory: last received value and the ``blend`` filter state.

    last : (L, d) last received ``x_j`` [m]; ``last_epoch`` (L,) the epoch it was sent (−1: none)
    blend : (L, d) ``b_j[k−1]`` [m]; ``has_blend`` (L,)
    """

    last: Array
    last_epoch: npt.NDArray[np.int64]
    blend: Array
    has_blend: Mask

    @classmethod
    def empty(cls, n_links: int, d: int) -> LinkMemory:
        return cls(
            last=np.zeros((n_links, d)),
            last_epoch=np.full(n_links, -1, dtype=np.int64),
            blend=np.zeros((n_links, d)),
            has_blend=np.zeros(n_links, dtype=bool),
        )

    def take(self, rows: npt.NDArray[np.int64]) -> LinkMemory:
        """The memory of the links ``rows`` only."""
        return LinkMemory(
            self.last[rows], self.last_epoch[rows], self.blend[rows], self.has_blend[rows]
        )

    def put(self, rows: npt.NDArray[np.int64], part: LinkMemory) -> LinkMemory:
        """This memory with the links ``rows`` replaced by ``part`` (the others kept)."""
        return LinkMemory(
            _scatter(self.last, rows, part.last),
            _scatter(self.last_epoch, rows, part.last_epoch),
            _scatter(self.blend, rows, part.blend),
            _scatter(self.has_blend, rows, part.has_blend),
        )

    def forget(self, rows: Mask) -> LinkMemory:
        """The links ``rows`` (L,) remember nothing: a receiver that (re)starts (issue 20)."""
        keep = ~rows
        return LinkMemory(
            self.last * keep[:, None],
            np.where(keep, self.last_epoch, -1),
            self.blend * keep[:, None],
            self.has_blend & keep,
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
    fallback : (L,) ``estimate``/``blend`` had no estimate and fell back to ``hold`` (or ``drop``)
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
    strategy: StrategyName,
    epoch: int,
    arrived: Mask,
    received: Array,
    memory: LinkMemory,
    estimate: Array,
    has_estimate: Mask,
    v_ref_prev: Array,
    period_s: float,
    alpha: float = 0.5,
) -> tuple[Substitution, LinkMemory]:
    """Fill lost coordination variables by ``strategy``.

    Parameters
    ----------
    strategy : ``zero``, ``hold``, ``estimate``, ``blend`` or ``drop``
    epoch : the current epoch ``k`` (stored with received values)
    arrived : (L,) the epoch-``k`` packet of the link arrived in time
    received : (L, d) its ``x_j[k]`` where arrived (ignored elsewhere) [m]
    memory : the links' memory from epoch ``k − 1``
    estimate : (L, d) the leader's ``x̂_j[k]`` [m]; ``has_estimate`` (L,) where it exists
    v_ref_prev : (d,) or (L, d) ``v_ref[k − 1]`` as each receiver knows it [m/s] (zero at k = 0)
    period_s : T [s]
    alpha : blend factor α ∈ (0, 1]

    Returns
    -------
    the substitution and the memory for epoch ``k + 1``
    """
    lost = ~arrived
    hold_ok = memory.has_last
    values = np.where(arrived[:, None], received, 0.0)
    fallback = np.zeros_like(arrived)
    blend, has_blend = memory.blend, memory.has_blend

    if strategy == "zero":
        have = lost.copy()  # x̃ = 0, the origin
    elif strategy == "hold":
        have = lost & hold_ok
        values = np.where(have[:, None], memory.last, values)
    elif strategy == "estimate":
        est = lost & has_estimate
        fallback = lost & ~has_estimate
        held = fallback & hold_ok
        values = np.where(est[:, None], estimate, np.where(held[:, None], memory.last, values))
        have = est | held
    elif strategy == "blend":
        predicted = blend + period_s * v_ref_prev
        est = lost & has_estimate
        # b[k] = α x̂ + (1 − α)(b[k−1] + T v_ref[k−1]); a filter with no past starts at the estimate.
        filtered = np.where(
            has_blend[:, None], alpha * estimate + (1.0 - alpha) * predicted, estimate
        )
        fallback = lost & ~has_estimate
        held = fallback & hold_ok
        values = np.where(est[:, None], filtered, np.where(held[:, None], memory.last, values))
        have = est | held
        # Without an estimate the filter only predicts; the value used is the held one (docs/model.md §6).
        blend = np.where(est[:, None], filtered, np.where(fallback[:, None], predicted, blend))
        has_blend = has_blend | est
    elif strategy == "drop":
        have = np.zeros_like(arrived)
    else:
        raise ValueError(
            f"unknown strategy {strategy!r}; expected zero, hold, estimate, blend or drop"
        )

    # A packet that arrives restarts the filter from the received value and is the new held value.
    new_memory = LinkMemory(
        last=np.where(arrived[:, None], received, memory.last),
        last_epoch=np.where(arrived, epoch, memory.last_epoch),
        blend=np.where(arrived[:, None], received, blend),
        has_blend=has_blend | arrived,
    )
    substitution = Substitution(
        values=values, used=arrived | have, substituted=have, fallback=fallback
    )
    return substitution, new_memory
