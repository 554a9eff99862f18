"""A run's headline numbers, computed once (docs/model.md §7), from its :class:`RunData`.

Every summary reads the same record and calls :func:`summarise`: ``report.md`` and
``summary.json`` (the recording as its trust gate passed it), ``formation run``'s (the
same ``summary.json``; the launcher's record of what it saw only without a recording) and
``formation simulate``'s (the simulator's). The sweep, which keeps only a
batch's arrays, takes its final errors by the same rule, :func:`team_errors` read by
:func:`final_value`. So the four agree to the last bit on the same states.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

import analysis.membership as membership
from analysis.air import air_losses, air_table
from analysis.membership import team_errors
from analysis.metrics import error_statistics, formation_error, longest_run
from analysis.queues import loss_split, queue_table
from analysis.record import RunData
from analysis.safety import safety_counts
from formation.air import AIR_QUEUE
from formation.rigidity import expected_rigidity_rank

Array = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]


def run_team_errors(run: RunData) -> tuple[Array, Array]:
    """(P,) formation and shape error [m] of ``run``'s team at each epoch (:func:`team_errors`)."""
    s = run.scenario
    return team_errors(
        run.positions,
        run.present,
        run.formation_error,
        run.shape_error,
        s.edge_array,
        s.weights,
        s.offsets,
    )


def summarise(run: RunData) -> dict[str, Any]:
    """The headline numbers of a run (docs/model.md §7); None where the run has no data.

    The final errors are the team's (:func:`team_errors`) at the last epoch with an agent
    in it (None if NaN there; a diverged run's inf stands).
    """
    s = run.scenario
    links = [f"{a}->{b}" for a, b in run.links]
    lost = run.decided & ~run.delivered
    _, _, sub_trace = error_statistics(run.substitution_errors)
    _, _, est_trace = error_statistics(run.estimation_errors)
    known = run.rigid >= 0
    tree = run.tree[known]
    expected = expected_rigidity_rank(s.n, s.dimension)
    formation, shape = run_team_errors(run)
    out: dict[str, Any] = {
        "label": run.label,
        "source": run.source,
        "scenario": s.name,
        "strategy": run.strategy,
        "seed": run.seed,
        "epochs": max(len(run.positions) - 1, 0),
        "epochs_with_states": int(np.isfinite(run.positions).all(axis=(1, 2)).sum()),
        "epochs_with_estimates": int(known.sum()),
        "final_formation_error_m": final_value(formation, run.present),
        "peak_formation_error_m": _peak(run.formation_error),
        "final_shape_error_m": final_value(shape, run.present),
        "peak_shape_error_m": _peak(run.shape_error),
        "substitutions": int(run.substitution_errors.shape[0]),
        "substitution_cov_trace_m2": _num(sub_trace),
        "estimation_cov_trace_m2": _num(est_trace),
        "nees_mean": _num(float(run.nees_values.mean())) if run.nees_values.size else None,
        "nees_expected": s.dimension,
        "covariance_every": s.estimator.covariance_every,
        "drops": {links[c]: int(v) for c, v in enumerate(lost.sum(axis=0)) if v},
        "longest_outage": {
            links[c]: longest_run(lost[:, c]) for c in range(len(links)) if lost[:, c].any()
        },
        "tree_changes": int((tree[1:] != tree[:-1]).any(axis=1).sum()) if len(tree) > 1 else 0,
        "epochs_not_rigid": int((run.rigid[known] == 0).sum()),
        "expected_rigidity_rank": expected,
        "epochs_split": int((run.components[known] > 1).sum()),
    }
    rec = run.recorded
    if rec is not None and rec.ended:
        out["ended"] = list(rec.ended)
    if rec is not None:
        out["skipped"] = rec.skipped.as_json()
    if run.deadlines is not None:
        out["deadlines"] = run.deadlines
    if s.network.capacity and run.decisions is not None:  # capacity (docs/model.md §9)
        judged = run.decisions.judged()
        queued = [j for j in judged if j.queue != AIR_QUEUE]  # the air is no queue
        out["queues"] = queue_table(queued, len(run.delivered))
        out["loss_split"] = loss_split(judged)
    if s.network.air is not None and run.decisions is not None:  # docs/model.md §11
        out["air"] = air_table(run.decisions)
        out["air_losses"] = air_losses(run.decisions.judged())
    out.update(_team(run))
    out["safety"] = safety_counts(s, run.positions, run.headings, run.saturated)
    recorded = None if rec is None else rec.formation_error
    if recorded is not None and np.isfinite(recorded).any():
        # the recorder's live metrics are the agents' states', never the robots' poses
        states_error = (
            run.formation_error
            if run.computed is None
            else formation_error(run.computed, s.edge_array, s.weights)
        )
        both = np.isfinite(recorded) & np.isfinite(states_error)
        gap = np.abs(recorded[both] - states_error[both])
        out["recorded_metrics_max_gap_m"] = float(gap.max()) if gap.size else None
    out.update(robot_tracking(run))
    if rec is not None and rec.robots:
        out["robot_counts"] = dict(rec.robots)
    return out


def robot_counts_line(counts: Mapping[str, int]) -> str:
    """The agents' counts of their robots' poses and commands, in words."""
    bad, jumps, frame = (counts.get(k, 0) for k in ("bad_poses", "jumps", "wrong_frame"))
    unstamped = counts.get("empty_frame", 0)
    return (
        f"robots: {counts.get('poses', 0)} poses, {bad + jumps + frame} rejected ({bad} not "
        f"finite, {jumps} jumps, {frame} in another frame), {counts.get('clipped', 0)} commands "
        f"clipped to the speed limit, {counts.get('resent', 0)} re-sent between steps"
        + (f", {unstamped} with no frame_id (taken as declared)" if unstamped else "")
    )


def tracking_lines(tracking: Mapping[str, Any]) -> list[str]:
    """Each robot's tracking error (:func:`robot_tracking`), and its warning, in words."""
    lines = [
        f"robot {i}: tracking error final {e['final_m']:.4g} m, peak {e['peak_m']:.4g} m, "
        f"RMS {e['rms_m']:.4g} m (its measured pose against its agent's state)"
        for i, e in tracking["robots"].items()
    ]
    return lines + ([tracking["warning"]] if tracking["warning"] else [])


def robot_tracking(run: RunData) -> dict[str, Any]:
    """Each robot's tracking error, its measured pose against its agent's state [m]: final,
    peak and RMS over the epochs it took part in; ``warning`` names those whose peak passes
    ``body.tracking_warning_m``. Empty without measured poses (``run.computed`` None)."""
    if run.computed is None:
        return {}
    gap = np.linalg.norm(run.positions - run.computed, axis=2)  # (P, n)
    threshold = run.scenario.body.tracking_warning_m
    per: dict[str, dict[str, float]] = {}
    for i in run.scenario.body.robots(run.scenario.n):
        seen = gap[np.isfinite(gap[:, i - 1]), i - 1]
        if seen.size:
            per[str(i)] = {
                "final_m": float(seen[-1]),
                "peak_m": float(seen.max()),
                "rms_m": float(np.sqrt(np.mean(seen**2))),
            }
    over = [i for i, t in per.items() if t["peak_m"] > threshold]
    warning = (
        f"warning: robot{'s' if len(over) > 1 else ''} {', '.join(over)} did not follow "
        f"{'their agents' if len(over) > 1 else 'its agent'}: tracking error above "
        f"{threshold:g} m (body.tracking_warning_m)"
        if over
        else None
    )
    return {"tracking": {"robots": per, "threshold_m": threshold, "warning": warning}}


def _team(run: RunData) -> dict[str, Any]:
    """Who was in the team at each epoch, when it changed, and the transient after each."""
    team = run.present
    if team.all() or not team.any():
        return {}
    s = run.scenario
    shape = membership.team_shape_error(run.positions, s.edge_array, s.offsets, team)
    events = [(e.epoch, e.agent, e.action) for e in s.events]
    return {
        "team": {str(i): spans for i, spans in membership.spans(team).items()},
        "team_changes": [vars(c) for c in membership.changes(team, shape, events=events)],
        "shape_threshold_m": membership.SHAPE_THRESHOLD_M,
    }


def final_value(values: Array, team: Mask) -> float | None:
    """``values`` (P,) at the last epoch with an agent in ``team`` (P, n); None if NaN."""
    seen = np.flatnonzero(team.any(axis=1))
    return None if not seen.size or np.isnan(values[seen[-1]]) else float(values[seen[-1]])


def _peak(values: Array) -> float | None:
    finite = values[np.isfinite(values)]
    return float(finite.max()) if finite.size else None


def _num(v: float) -> float | None:
    return None if v is None or not math.isfinite(v) else float(v)


__all__ = ["final_value", "run_team_errors", "summarise"]
