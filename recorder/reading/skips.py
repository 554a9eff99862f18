"""Why a recording's message is not trusted: the reasons, the exception that carries one, the count.

:class:`~recorder.reading.trust.Gate` raises :class:`Skip` inside its checks and counts each
in :class:`Skipped`, per channel and reason.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any

INVALID = "invalid"  # not JSON (protobuf), wrong fields or types, non-finite or mis-sized numbers
FORGED = "forged"  # the sender does not own the key, or claims another agent's id
OUT_OF_RANGE = "out of range"  # an epoch, agent id, link or edge the scenario does not have
CONFLICT = "conflict"  # a second, different message of the same key and epoch
UNKNOWN_KEY = "unknown key"  # a key that no process of the testbed publishes on
REASONS = (INVALID, FORGED, OUT_OF_RANGE, CONFLICT, UNKNOWN_KEY)


class Skip(Exception):
    """Why a message is not trusted; caught inside :meth:`recorder.reading.trust.Gate.check`."""

    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(detail or reason)
        self.reason = reason


@dataclass
class Skipped:
    """Messages a :class:`~recorder.reading.trust.Gate` refused: per channel (topic) and reason, with a few examples."""

    counts: Counter[tuple[str, str]] = field(default_factory=Counter)
    examples: list[tuple[str, str, str]] = field(default_factory=list)  # topic, reason, detail
    limit: int = 20

    def add(self, topic: str, reason: str, detail: str) -> None:
        self.counts[topic, reason] += 1
        if len(self.examples) < self.limit:
            self.examples.append((topic, reason, detail[:200]))

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def by_channel(self) -> dict[str, int]:
        out: Counter[str] = Counter()
        for (topic, _), v in self.counts.items():
            out[topic] += v
        return dict(sorted(out.items()))

    def by_reason(self) -> dict[str, int]:
        out: Counter[str] = Counter()
        for (_, reason), v in self.counts.items():
            out[reason] += v
        return {r: out[r] for r in REASONS if out[r]}

    def as_json(self) -> dict[str, Any]:
        """``{"total", "by_reason", "by_channel": {topic: {reason: n}}}`` (summary.json)."""
        nested: dict[str, dict[str, int]] = {}
        for (topic, reason), v in sorted(self.counts.items()):
            nested.setdefault(topic, {})[reason] = v
        return {"total": self.total, "by_reason": self.by_reason(), "by_channel": nested}

    def describe(self, prefix: str = "") -> str:
        """One line: ``12 messages skipped (forged 3, invalid 9) on 4 channels``."""
        if not self.total:
            return "no message skipped"
        reasons = ", ".join(f"{r} {v}" for r, v in self.by_reason().items())
        return f"{self.total} messages skipped ({reasons}) on {len(self.by_channel())} channels"


__all__ = [
    "CONFLICT",
    "FORGED",
    "INVALID",
    "OUT_OF_RANGE",
    "REASONS",
    "UNKNOWN_KEY",
    "Skip",
    "Skipped",
]
