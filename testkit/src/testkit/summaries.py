"""One summary, every field: a recording's ``summary.json`` against the simulator's summary."""

from __future__ import annotations

import json
from typing import Any

# Where the record came from, not what it holds: the recording's path, its trust gate's skips,
# the processes it saw end and the gap to the metrics it carried.
PROVENANCE = ("label", "source", "skipped", "ended", "recorded_metrics_max_gap_m")


def summary_differences(recorded: dict[str, Any], simulated: dict[str, Any]) -> list[str]:
    """The fields, provenance aside, that only one summary has or whose values differ in any
    bit (compared as JSON holds them: a float's repr is its every bit)."""
    a, b = json.loads(json.dumps(recorded)), json.loads(json.dumps(simulated))
    keys = (a.keys() | b.keys()) - set(PROVENANCE)
    return sorted(k for k in keys if k not in a or k not in b or repr(a[k]) != repr(b[k]))


__all__ = ["PROVENANCE", "summary_differences"]
