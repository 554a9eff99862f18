"""What runs of one scenario show, in sentences computed from their records (docs/model.md §6–§7).

Which strategies keep the formation and by how much; why two strategies move identically
(every lost packet an agent steered by was the reference agent's, which the leader knows
exactly; or the estimate fell back to ``hold`` because an agent was unobservable); and why
``drop`` converges or not (the healthy graph's connectivity and rigidity, against what the
controller needs). Pure: records in, text out.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from analysis import RunData, final_value, run_team_errors

KEEP_M = 0.05  # [m] a run keeps the formation when its final formation error is under this
GRAPH_NEEDS = {"displacement": "connected", "distance": "rigid"}  # what a controller needs


@dataclass(frozen=True)
class Evidence:
    """What one run tells about its strategy: the facts the sentences are made of.

    steering : lost packets an agent steered by (the reference agent steers by none)
    exact : of those, filled with the true position
    from_reference : of those, the reference agent's
    fallbacks : substitutions that fell back to ``hold`` (no estimate for the neighbour)
    unobservable : agent → epochs the leader could not observe it, for agents it fell back for
    epochs : epochs with the leader's view; split, not_rigid : of those, the healthy graph
    was not connected, not rigid (−1: not known)
    """

    final_m: float | None
    steering: int
    exact: int
    from_reference: int
    fallbacks: int
    unobservable: dict[int, int]
    epochs: int
    split: int
    not_rigid: int


def evidence(run: RunData) -> Evidence:
    """The facts of ``run`` (:class:`Evidence`)."""
    formation, _ = run_team_errors(run)
    ref = run.scenario.reference_agent
    subs = run.substitutions
    steering = exact = from_reference = fallbacks = 0
    unobservable: dict[int, int] = {}
    if subs is not None and subs.epoch.size:
        steer = subs.agent != ref
        errors = subs.errors(run.positions)
        steering = int(steer.sum())
        exact = int((steer & (errors == 0.0).all(axis=1)).sum())
        from_reference = int((steer & (subs.neighbour == ref)).sum())
        fallbacks = int(subs.fallback.sum())
        seen = run.observable
        for j in np.unique(subs.neighbour[subs.fallback]).tolist():
            if len(seen) and not seen[:, j - 1].all():
                unobservable[int(j)] = int((~seen[:, j - 1]).sum())
    known = run.rigid >= 0
    return Evidence(
        final_m=final_value(formation, run.present),
        steering=steering,
        exact=exact,
        from_reference=from_reference,
        fallbacks=fallbacks,
        unobservable=dict(sorted(unobservable.items())),
        epochs=int(known.sum()),
        split=int((run.components[known] > 1).sum()),
        not_rigid=int((run.rigid[known] == 0).sum()),
    )


def identical(a: RunData, b: RunData) -> bool:
    """The two runs' positions are equal to the bit at every epoch."""
    return a.positions.shape == b.positions.shape and bool(
        np.array_equal(a.positions, b.positions, equal_nan=True)
    )


def identical_groups(runs: Sequence[RunData]) -> list[list[int]]:
    """Indices of ``runs`` grouped by identical positions, groups of two or more, in order."""
    groups: list[list[int]] = []
    for i, run in enumerate(runs):
        for g in groups:
            if identical(runs[g[0]], run):
                g.append(i)
                break
        else:
            groups.append([i])
    return [g for g in groups if len(g) > 1]


def why_identical(facts: Sequence[Evidence], reference_agent: int) -> str:
    """Why runs with these facts moved identically, as a clause ("…: <clause>")."""
    if all(f.steering == 0 for f in facts):
        return "no agent lost a packet it steers by, so the strategies never acted"
    if all(f.exact == f.steering for f in facts):
        if all(f.from_reference == f.steering for f in facts):
            return (
                f"every lost packet an agent steered by was agent {reference_agent}'s, the "
                "reference agent, whose position the leader knows exactly, so each filled in "
                "the true position"
            )
        return "each filled in the true position for every lost packet an agent steered by"
    if all(f.fallbacks >= f.steering for f in facts):
        return "every lost packet an agent steered by was filled by hold (no estimate for it)"
    return "their fills differ, yet the agents took the same steps"


def fallback_clause(labels: Sequence[str], f: Evidence) -> str | None:
    """Why the strategies ``labels`` fell back to hold, or None if they never did."""
    if not f.fallbacks:
        return None
    each = " each" if len(labels) > 1 else ""
    head = f"{_join([_code(x) for x in labels])} fell back to hold {f.fallbacks} times{each}"
    if f.unobservable:
        agents = _join(
            [f"agent {j} in {k} of {f.epochs} epochs" for j, k in f.unobservable.items()]
        )
        return (
            f"{head}: the leader could not observe {agents} (cut off from the reference agent "
            "in the healthy graph), so it had no estimate to send"
        )
    return f"{head}: the leader's estimate packet was lost"


def graph_clause(controller: str, f: Evidence) -> str:
    """The healthy graph (the links that delivered) over the run against what ``controller`` needs."""
    connected = (
        "connected in every epoch" if not f.split else f"split in {f.split} of {f.epochs} epochs"
    )
    rigid = (
        "rigid in every epoch" if not f.not_rigid else f"not rigid in {f.not_rigid} of {f.epochs}"
    )
    need = GRAPH_NEEDS.get(controller)
    if need == "connected":
        rigidity = f"it was {rigid}: only the distance controller needs rigidity"
        if f.split:
            return (
                f"the healthy graph was {connected} and connected in the others; displacement "
                f"consensus needs it connected ({rigidity})"
            )
        return f"the healthy graph was {connected}, which is all displacement consensus needs ({rigidity})"
    if need == "rigid":
        if f.not_rigid:
            return (
                f"the healthy graph was {rigid} epochs and rigid in the others ({connected}); "
                "the distance controller needs it rigid"
            )
        return f"the healthy graph was {rigid} ({connected}), which the distance controller needs"
    return f"the healthy graph was {connected} and {rigid}"


def keep_sentence(finals: Sequence[tuple[str, float | None]]) -> str:
    """Which of ``(label, final formation error [m])`` keep the formation, by how much."""
    known = [(label, v) for label, v in finals if v is not None and np.isfinite(v)]
    kept = sorted(((label, v) for label, v in known if v < KEEP_M), key=lambda lv: lv[1])
    lost = sorted(((label, v) for label, v in known if v >= KEEP_M), key=lambda lv: lv[1])
    parts = []
    if kept:
        verb = "keeps" if len(kept) == 1 else "keep"
        parts.append(
            f"{_names(kept)} {verb} the formation (final formation error {_values(kept)}, "
            f"under the {KEEP_M:g} m threshold)"
        )
    if lost:
        if kept:
            best = kept[0][1]
            times = _join([f"{v / best:.0f}×" for _, v in lost])
            verb = "loses" if len(lost) == 1 else "lose"
            parts.append(
                f"{_names(lost)} {verb} it ({_values(lost)}: {times} {_code(kept[0][0])}'s)"
            )
        elif len(lost) == 1:
            parts.append(
                f"{_names(lost)} loses the formation (final formation error {_values(lost)}, "
                f"over the {KEEP_M:g} m threshold)"
            )
        else:
            parts.append(
                f"no strategy keeps the formation (final formation error {_values(lost)}, "
                f"all over the {KEEP_M:g} m threshold)"
            )
    gone = [label for label, v in finals if v is None or not np.isfinite(v)]
    if gone:
        parts.append(f"{_join([_code(x) for x in gone])} ended without a final formation error")
    return _sentence("; ".join(parts))


def names(runs: Sequence[RunData]) -> list[str]:
    """What to call each run: its strategy when that tells the runs apart (one scenario and
    seed, a strategy each), else its label."""
    strategies = [r.strategy for r in runs]
    alike = len({(r.scenario.name, r.seed) for r in runs}) == 1
    return strategies if alike and len(set(strategies)) == len(runs) else [r.label for r in runs]


def conclusion(runs: Sequence[RunData]) -> list[str]:
    """Two or three sentences on ``runs`` (one scenario): keep, coincide, why ``drop``."""
    facts = [evidence(r) for r in runs]
    called = names(runs)
    out = [keep_sentence([(c, f.final_m) for c, f in zip(called, facts, strict=True)])]
    ref = runs[0].scenario.reference_agent
    for group in identical_groups(runs):
        together = _join([_code(called[i]) for i in group])
        why = why_identical([facts[i] for i in group], ref)
        out.append(_sentence(f"{together} move identically, to the bit: {why}"))
    fell: dict[tuple[int, tuple[tuple[int, int], ...]], list[int]] = {}
    for i, f in enumerate(facts):
        if f.fallbacks:
            fell.setdefault((f.fallbacks, tuple(f.unobservable.items())), []).append(i)
    for rows in fell.values():
        clause = fallback_clause([called[i] for i in rows], facts[rows[0]])
        out.append(_sentence(clause or ""))
    for r, c, f in zip(runs, called, facts, strict=True):
        if r.strategy == "drop" and f.final_m is not None:
            verb = "converges" if f.final_m < KEEP_M else "does not converge"
            graph = graph_clause(r.scenario.control.controller, f)
            out.append(
                _sentence(f"{_code(c)} {verb}: it steers by the healthy links alone, and {graph}")
            )
    return out


def coincidence_notes(runs: Sequence[RunData]) -> dict[int, str]:
    """Index → a figure's note for each run drawn identically to an earlier one."""
    called, notes = names(runs), {}
    for group in identical_groups(runs):
        for i in group[1:]:
            notes[i] = f"identical to {called[group[0]]}"
    return notes


def _code(label: str) -> str:
    return f"`{label}`"


def _names(pairs: Sequence[tuple[str, float]]) -> str:
    return _join([_code(label) for label, _ in pairs])


def _values(pairs: Sequence[tuple[str, float]]) -> str:
    """``0.00477, 0.00477 and 0.00507 m``, or each named when the list is long."""
    if len(pairs) > 3:
        return _join([f"{_code(label)} {v:.3g} m" for label, v in pairs])
    return _join([f"{v:.3g}" for _, v in pairs]) + " m"


def _join(words: Sequence[str]) -> str:
    if len(words) <= 2:
        return " and ".join(words)
    return ", ".join(words[:-1]) + " and " + words[-1]


def _sentence(text: str) -> str:
    return text[:1].upper() + text[1:] + "." if text else ""  # a leading `label` stays as it is


__all__ = [
    "GRAPH_NEEDS",
    "KEEP_M",
    "Evidence",
    "coincidence_notes",
    "conclusion",
    "evidence",
    "fallback_clause",
    "graph_clause",
    "identical",
    "identical_groups",
    "keep_sentence",
    "names",
    "why_identical",
]
