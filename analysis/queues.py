"""A run's capacity queues from netem's records: load, throughput, depth, drops by reason.

netem records every packet its queues judged (``Decision.queue``, docs/model.md §9), and a
queue's drop has its reason as ``model``: ``queue_full`` and ``oversize`` (refused by the
queue), ``queue_late`` (left it after its phase's deadline). Every other drop is the
channel's, by a link model. Pure: records in, numbers out.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any, NamedTuple, Protocol

QUEUE_REASONS = ("queue_full", "oversize")  # refused by the queue
DEADLINE_REASONS = ("queue_late",)  # left the queue after the phase's deadline


class Judged(NamedTuple):
    """One record as the analysis keeps it."""

    epoch: int
    verdict: str
    model: str
    queue: str | None
    depth: int | None
    sojourn_ms: float | None


class Verdicted(Protocol):
    """A decision record as anyone keeps it: its verdict and what decided it."""

    @property
    def verdict(self) -> str: ...

    @property
    def model(self) -> str: ...


def loss_split(records: Iterable[Verdicted]) -> dict[str, int]:
    """Drops by where they happened: ``channel`` (link models), ``queue``, ``deadline``."""
    out = {"channel": 0, "queue": 0, "deadline": 0}
    for r in records:
        if r.verdict != "drop":
            continue
        key = (
            "queue"
            if r.model in QUEUE_REASONS
            else "deadline"
            if r.model in DEADLINE_REASONS
            else "channel"
        )
        out[key] += 1
    return out


def queue_table(records: Iterable[Judged], epochs: int) -> dict[str, dict[str, Any]]:
    """Per queue: packets offered and passed (per epoch too), depth and sojourn, drops by reason.

    ``depth`` is the queue's length when a packet came [packets]; ``sojourn`` a passed
    packet's time in the queues [ms].
    """
    out: dict[str, dict[str, Any]] = {}
    for r in records:
        if r.queue is None:
            continue
        q = out.setdefault(
            r.queue,
            {"offered": 0, "passed": 0, "drops": {}, "depth": [], "sojourn_ms": [], "by_epoch": {}},
        )
        q["offered"] += 1
        if r.depth is not None:
            q["depth"].append(r.depth)
            q["by_epoch"].setdefault(r.epoch, []).append(r.depth)
        if r.verdict == "drop":
            q["drops"][r.model] = q["drops"].get(r.model, 0) + 1
        else:
            q["passed"] += 1
            if r.sojourn_ms is not None:
                q["sojourn_ms"].append(r.sojourn_ms)
    per = max(epochs, 1)
    return {
        name: {
            "offered": q["offered"],
            "passed": q["passed"],
            "offered_per_epoch": q["offered"] / per,
            "throughput_per_epoch": q["passed"] / per,
            "drops": dict(sorted(q["drops"].items())),
            "mean_depth": _mean(q["depth"]),
            "max_depth": max(q["depth"], default=None),
            "mean_sojourn_ms": _mean(q["sojourn_ms"]),
            "max_sojourn_ms": max(q["sojourn_ms"], default=None),
            # the queue's depth over time: the largest a packet found in each epoch
            "max_depth_by_epoch": {str(k): max(v) for k, v in sorted(q["by_epoch"].items())},
        }
        for name, q in sorted(out.items())
    }


def _mean(values: list[Any]) -> float | None:
    return sum(values) / len(values) if values else None


__all__ = [
    "DEADLINE_REASONS",
    "QUEUE_REASONS",
    "Judged",
    "Verdicted",
    "loss_split",
    "queue_table",
]
