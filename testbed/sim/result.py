"""What one simulated run produced (``testbed.sim.simulate``, or one member of a batch)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from recorder import RunData, summarise

Array = npt.NDArray[np.float64]


@dataclass(kw_only=True)
class SimResult(RunData):
    """A run's record (:class:`recorder.RunData`) as the simulator makes it, with what only the
    simulator knows; row ``i − 1`` is agent ``i``, ``E`` epochs.

    Every delivery is decided; in the team is whoever published ``x[k]``
    (``Membership.published``: the bodies out of it stay where they were).
    report_ok, estimate_ok : (E, n) control links delivered in time
    substitution_epochs : (N,) the epoch of each of ``substitution_errors``' rows
    fallbacks : substitutions that fell back to ``hold`` (no estimate to use)
    """

    report_ok: npt.NDArray[np.bool_]
    estimate_ok: npt.NDArray[np.bool_]
    substitution_epochs: npt.NDArray[np.int64]
    fallbacks: int

    def __post_init__(self) -> None:
        if self.present.shape != self.positions.shape[:2]:
            self.present = self.scenario.membership.published
        super().__post_init__()

    def record(self, label: str | None = None) -> RunData:
        """The run's record under ``label`` (default: its strategy): a copy sharing the arrays,
        so that setting a field of it leaves this result as it was."""
        return replace(self, label=label or self.label)

    def summary(self) -> dict[str, Any]:
        """The headline numbers of the run (what ``formation simulate`` prints), as
        :func:`recorder.summarise` gives them for its :meth:`record`."""
        full = summarise(self.record())
        out = {"scenario": self.scenario.name, "strategy": self.strategy, "seed": self.seed}
        out |= {k: full[k] for k in _HEADLINE}
        out["fallbacks"] = self.fallbacks
        out |= {k: full[k] for k in _ESTIMATION}
        return out


_HEADLINE = (
    "epochs",
    "final_formation_error_m",
    "peak_formation_error_m",
    "final_shape_error_m",
    "peak_shape_error_m",
    "substitutions",
    "substitution_cov_trace_m2",
)
_ESTIMATION = ("estimation_cov_trace_m2", "nees_mean", "drops", "longest_outage", "safety")


__all__ = ["SimResult"]
