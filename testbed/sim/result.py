"""What one simulated run produced (``testbed.sim.simulate``, or one member of a batch)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from formation.scenario import Scenario, StrategyName
from recorder import RunData, summarise

Array = npt.NDArray[np.float64]


@dataclass
class SimResult:
    """Everything one simulated run produced; row ``i − 1`` is agent ``i``, ``E`` epochs.

    positions : (E + 1, n, d) true positions [m]
    formation_error, shape_error : (E + 1,) [m]
    estimates : (E, n, d) leader's BLUE (NaN where unobservable); estimate_cov (E, n, d, d)
    delivered : (E, L) formation link ``directed_links[l]`` delivered in time at epoch k
    report_ok, estimate_ok : (E, n) control links delivered in time
    healthy, tree : (E, m) per formation edge
    components, rigidity_rank : (E,)
    substitution_errors : (N, d) ``x̃_j − x_j`` of every substituted variable [m]
    headings : (E + 1, n) [rad], saturated : (E, n) sub-steps with a clipped speed (unicycle only)
    """

    scenario: Scenario
    strategy: StrategyName
    seed: int
    positions: Array
    formation_error: Array
    shape_error: Array
    estimates: Array
    estimate_cov: Array
    observable: npt.NDArray[np.bool_]
    delivered: npt.NDArray[np.bool_]
    report_ok: npt.NDArray[np.bool_]
    estimate_ok: npt.NDArray[np.bool_]
    healthy: npt.NDArray[np.bool_]
    tree: npt.NDArray[np.bool_]
    components: npt.NDArray[np.int64]
    rigidity_rank: npt.NDArray[np.int64]
    substitution_errors: Array
    substitution_epochs: npt.NDArray[np.int64]
    fallbacks: int
    nees_values: Array
    estimation_errors: Array
    extra: dict[str, Any] = field(default_factory=dict)
    headings: Array | None = None
    saturated: npt.NDArray[np.int64] | None = None

    def record(self, label: str | None = None) -> RunData:
        """The run as the recorder reads one back: every delivery decided, and in the team
        whoever published ``x[k]`` (the bodies out of it stay where they were)."""
        return RunData(
            label=label or self.strategy,
            scenario=self.scenario,
            strategy=self.strategy,
            seed=self.seed,
            positions=self.positions,
            present=self.scenario.membership.published,
            formation_error=self.formation_error,
            shape_error=self.shape_error,
            estimates=self.estimates,
            estimate_cov=self.estimate_cov,
            observable=self.observable,
            delivered=self.delivered,
            healthy=self.healthy,
            tree=self.tree,
            components=self.components,
            rigidity_rank=self.rigidity_rank,
            substitution_errors=self.substitution_errors,
            nees_values=self.nees_values,
            estimation_errors=self.estimation_errors,
            headings=self.headings,
            saturated=self.saturated,
        )

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
