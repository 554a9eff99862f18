"""What one variant of an experiment shows over its seeds, in sentences computed from the batches.

The per-seed facts are the run report's (``recorder.evidence`` on each seed's record); here
they are pooled: how many seeds each strategy keeps the formation in, with the mean and
spread of its final error; which strategies move identically in every seed and why; how
often the estimate fell back to hold; why ``drop`` converges or not.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from recorder import KEEP_M, Evidence, evidence, fallback_clause, graph_clause, why_identical
from testbed.experiments.grid import KEEP_FRACTION
from testbed.experiments.paper import final_errors
from testbed.sim.batch import BatchResult

CLOSE = 0.1  # a kept strategy within this fraction of the best one's mean final error is "close"


def _mean_std(v: np.ndarray) -> str:
    return f"{np.mean(v):.3g} ± {np.std(v):.2g}"


def _code(name: str) -> str:
    return f"`{name}`"


def _join(words: Sequence[str]) -> str:
    return " and ".join(words) if len(words) <= 2 else ", ".join(words[:-1]) + " and " + words[-1]


def _pooled(facts: Sequence[Evidence]) -> Evidence:
    """The seeds' facts summed (finals: the mean)."""
    finals = [f.final_m for f in facts if f.final_m is not None]
    unobservable: dict[int, int] = {}
    for f in facts:
        for j, k in f.unobservable.items():
            unobservable[j] = unobservable.get(j, 0) + k
    return Evidence(
        final_m=float(np.mean(finals)) if finals else None,
        steering=sum(f.steering for f in facts),
        exact=sum(f.exact for f in facts),
        from_reference=sum(f.from_reference for f in facts),
        fallbacks=sum(f.fallbacks for f in facts),
        unobservable=dict(sorted(unobservable.items())),
        epochs=sum(f.epochs for f in facts),
        split=sum(f.split for f in facts),
        not_rigid=sum(f.not_rigid for f in facts),
    )


def _in_seeds(counts: Sequence[int], seeds: int) -> str:
    """``in all 20 seeds`` or ``in 19, 20 and 12 of 20 seeds``."""
    if all(c == seeds for c in counts):
        return f"in all {seeds} seeds" if len(counts) > 1 or seeds > 1 else "in its seed"
    return f"in {_join([str(c) for c in counts])} of {seeds} seeds"


def keep_sentence(runs: Mapping[str, BatchResult]) -> str:
    """Which strategies keep the formation in most seeds, by how much, over the seeds."""
    finals = {s: final_errors(res) for s, res in runs.items()}
    seeds = len(next(iter(finals.values())))
    kept = {s: int(np.sum(v < KEEP_M)) for s, v in finals.items()}
    mean = {s: float(np.mean(v)) for s, v in finals.items()}
    good = sorted((s for s in finals if kept[s] >= KEEP_FRACTION * seeds), key=mean.__getitem__)
    bad = sorted((s for s in finals if s not in good), key=mean.__getitem__)
    same = identical_notes(runs)
    parts = []
    if good:
        parts.append(
            f"{_join([_code(s) for s in good])} {'keeps' if len(good) == 1 else 'keep'} the formation "
            f"{_in_seeds([kept[s] for s in good], seeds)} (final formation error "
            f"{_join([_mean_std(finals[s]) for s in good])} m, mean ± standard deviation; "
            f"threshold {KEEP_M:g} m)"
        )
        best = mean[good[0]]
        close = [
            f"{_code(s)} ends within {abs(mean[s] / best - 1):.0%} of {_code(good[0])} on average"
            for s in good[1:]
            if s not in same and abs(mean[s] / best - 1) <= CLOSE
        ]
        parts += close
    if bad:
        ratio = (
            ""
            if not good
            else ": "
            + _join([f"{mean[s] / mean[good[0]]:.0f}×" for s in bad])
            + f" {_code(good[0])}'s"
        )
        parts.append(
            f"{_join([_code(s) for s in bad])} {'loses' if len(bad) == 1 else 'lose'} it "
            f"{_in_seeds([seeds - kept[s] for s in bad], seeds)} "
            f"({_join([_mean_std(finals[s]) for s in bad])} m{ratio})"
        )
    text = "; ".join(parts)
    return text[:1].upper() + text[1:] + "."


def identical_notes(runs: Mapping[str, BatchResult], field: str = "positions") -> dict[str, str]:
    """Strategy → "identical to <earlier strategy>" where ``field`` is equal to the bit."""
    names, notes = list(runs), {}
    for i, b in enumerate(names):
        for a in names[:i]:
            if a not in notes and _same(getattr(runs[a], field), getattr(runs[b], field)):
                notes[b] = f"identical to {a}"
                break
    return notes


def _same(x: np.ndarray, y: np.ndarray) -> bool:
    return x.shape == y.shape and bool(np.array_equal(x, y, equal_nan=True))


def noise_floor(runs: Mapping[str, BatchResult]) -> float | None:
    """``drop``'s mean final formation error when it keeps the formation (it leaves lost
    terms out, so only the measurement noise is left) [m]; None otherwise."""
    if "drop" not in runs:
        return None
    mean = float(np.mean(final_errors(runs["drop"])))
    return mean if mean < KEEP_M else None


def conclusion(runs: Mapping[str, BatchResult]) -> list[str]:
    """Two or three sentences on one variant: keep, coincide, fall back, why ``drop``."""
    out = [keep_sentence(runs)]
    names = list(runs)
    first = next(iter(runs.values()))
    size = first.size
    facts = {s: [evidence(res.member(b)) for b in range(size)] for s, res in runs.items()}
    done: set[str] = set()
    for i, a in enumerate(names):
        same = [
            b
            for b in names[i + 1 :]
            if b not in done
            and np.array_equal(runs[a].positions, runs[b].positions, equal_nan=True)
        ]
        if same:
            done.update(same)
            group = [a, *same]
            why = why_identical(
                [f for s in group for f in facts[s]], first.plan.base.reference_agent
            )
            out.append(
                f"{_join([_code(s) for s in group])} move identically, to the bit, in every seed: {why}."
            )
    fell: dict[int, list[str]] = {}
    for s in names:
        pooled = _pooled(facts[s])
        if pooled.fallbacks:
            fell.setdefault(pooled.fallbacks, []).append(s)
    for group in fell.values():
        clause = fallback_clause(group, _pooled(facts[group[0]]))
        if clause:
            out.append(f"Over the {size} seeds, {clause}.")
    if "drop" in runs:
        pooled = _pooled(facts["drop"])
        mean = pooled.final_m
        verb = "converges" if mean is not None and mean < KEEP_M else "does not converge"
        graph = graph_clause(first.plan.base.control.controller, pooled)
        out.append(
            f"`drop` {verb}: it steers by the healthy links alone, and over the {size} seeds "
            f"({pooled.epochs} epochs in all) {graph}."
        )
    return out


__all__ = ["CLOSE", "conclusion", "identical_notes", "keep_sentence", "noise_floor"]
