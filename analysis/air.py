"""A run's shared air from netem's records: what took the air, what arrived, losses by cause.

netem records every packet the air judged with ``queue = "air"`` (docs/model.md §11); a drop
there has its cause as ``model`` (``formation.air.AIR_CAUSES``) and a delivered packet its
arrival in its phase as ``sojourn_ms``. A packet a link model dropped never took the air.
Pure: records in, numbers out.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

from analysis.queues import Verdicted
from analysis.record import Decisions
from formation.air import AIR_CAUSES, AIR_QUEUE


def air_table(decisions: Decisions) -> dict[str, dict[str, Any]]:
    """Per link class on the air: packets that took it, delivered, losses by cause, and the
    mean and largest arrival time in the phase [ms] (None when the record has none)."""
    on = np.array([q == AIR_QUEUE for q in decisions.queue], dtype=bool)
    out: dict[str, dict[str, Any]] = {}
    for cls in ("formation", "report", "estimate"):
        rows = on & (decisions.link_class == cls)
        if not rows.any():
            continue
        passed = rows & (decisions.verdict != "drop")
        arrival = decisions.sojourn_ms[passed]
        arrival = arrival[np.isfinite(arrival)]
        models = decisions.model[rows & (decisions.verdict == "drop")].tolist()
        out[cls] = {
            "took_air": int(rows.sum()),
            "delivered": int(passed.sum()),
            "losses": {c: models.count(c) for c in AIR_CAUSES if c in models},
            "mean_arrival_ms": float(arrival.mean()) if arrival.size else None,
            "max_arrival_ms": float(arrival.max()) if arrival.size else None,
        }
    return out


def air_losses(records: Iterable[Verdicted]) -> dict[str, int]:
    """The air's drops by cause (every cause, 0 where none)."""
    out = dict.fromkeys(AIR_CAUSES, 0)
    for r in records:
        if r.verdict == "drop" and r.model in out:
            out[r.model] += 1
    return out


__all__ = ["air_losses", "air_table"]
