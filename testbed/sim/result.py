"""What one simulated run produced (``testbed.sim.simulate``, or one member of a batch)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from formation.scenario import Scenario, StrategyName
from recorder import error_statistics, final_team_errors, longest_run, safety_counts

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

    def summary(self) -> dict[str, Any]:
        """The headline numbers of the run (what ``formation simulate`` prints)."""
        _, _sub_cov, sub_trace = error_statistics(self.substitution_errors)
        _, _est_cov, est_trace = error_statistics(self.estimation_errors)
        drops = (~self.delivered).sum(axis=0)
        s = self.scenario
        links = s.directed_links
        last = np.where(s.membership.present[-1][:, None], self.positions[-1], np.nan)
        final = final_team_errors(last, s.edge_array, s.weights, s.offsets) or (
            float(self.formation_error[-1]),
            float(self.shape_error[-1]),
        )  # over the team taking part at the end, as formation run and the sweep judge it
        return {
            "scenario": s.name,
            "strategy": self.strategy,
            "seed": self.seed,
            "epochs": int(self.positions.shape[0] - 1),
            "final_formation_error_m": final[0],
            "peak_formation_error_m": float(self.formation_error.max()),
            "final_shape_error_m": final[1],
            "peak_shape_error_m": float(self.shape_error.max()),
            "substitutions": int(self.substitution_errors.shape[0]),
            "substitution_cov_trace_m2": _none_if_nan(sub_trace),
            "fallbacks": self.fallbacks,
            "estimation_cov_trace_m2": _none_if_nan(est_trace),
            "nees_mean": _none_if_nan(
                float(self.nees_values.mean()) if self.nees_values.size else float("nan")
            ),
            "drops": {
                f"{int(a)}->{int(b)}": int(c) for (a, b), c in zip(links, drops, strict=True) if c
            },
            "longest_outage": {
                f"{int(a)}->{int(b)}": longest_run(~self.delivered[:, k])
                for k, (a, b) in enumerate(links)
                if drops[k]
            },
            "safety": safety_counts(self.scenario, self.positions, self.headings, self.saturated),
        }


def _none_if_nan(v: float) -> float | None:
    return None if np.isnan(v) else v


__all__ = ["SimResult"]
