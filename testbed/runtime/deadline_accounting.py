"""A realtime run's packets, accounted for: modelled losses, deadline misses by cause, in time.

The receivers (agents, pools, the leader) count what they took in time and each miss by
its cause; netem counts the packets its models delayed past their deadline
(formation.deadlines). Their final statuses carry the counts as JSON in ``detail``.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Iterable, Mapping
from typing import Any

from formation.deadlines import WARN_RATE, summarise
from formation.messages import Status

NETEM = "netem."  # the prefix of netem's counts among the run's


def deadline_counts(statuses: Iterable[Status]) -> dict[str, int]:
    """The receivers' counts summed, and netem's under :data:`NETEM`; unreadable details skipped."""
    counts: Counter[str] = Counter()
    for st in statuses:
        if st.role not in ("agent", "pool", "leader", "netem") or not st.detail.startswith("{"):
            continue
        try:
            detail = json.loads(st.detail)
            got = {str(k): int(v) for k, v in detail.items()}
        except (ValueError, TypeError, AttributeError):
            continue  # a forged or broken status: its counts are not trusted
        prefix = NETEM if st.role == "netem" else ""
        counts.update({prefix + k: v for k, v in got.items()})
    return dict(counts)


def realtime_accounting(
    counts: Mapping[str, int],
    drops: Mapping[str, tuple[int, int]],
    cpu_steal: float | None = None,
) -> dict[str, Any]:
    """Every packet netem decided, as modelled losses, deadline misses or delivered in time.

    ``counts``: :func:`deadline_counts` (none in lockstep: only ``deadline_miss_rate``, None);
    ``drops``: netem's ``link → (sent, dropped)`` by its models. ``unaccounted``: the
    packets none of the three took (e.g. still on their way when the run ended); 0 when
    the books balance. ``warning``: a line to print when misses exceed :data:`WARN_RATE`;
    it names ``cpu_steal`` (the hypervisor's share of the CPU during the run) when some was
    taken: on a shared VM that, more than the testbed, made the misses.
    """
    if not counts:
        return {"deadline_miss_rate": None}
    sent, dropped = sum(s for s, _ in drops.values()), sum(d for _, d in drops.values())
    netem = {k.removeprefix(NETEM): v for k, v in counts.items() if k.startswith(NETEM)}
    got = summarise({k: v for k, v in counts.items() if not k.startswith(NETEM)}, netem)
    misses = {"total": got.misses, "by_cause": got.by_cause}
    modelled = dropped + got.modelled_late
    rate = got.misses / sent if sent else None
    warning = None
    if rate is not None and rate > WARN_RATE:
        causes = ", ".join(f"{c} {n}" for c, n in got.by_cause.items() if n)
        warning = (
            f"warning: {got.misses} packets ({100 * rate:.2f} %) missed their deadline "
            f"of the testbed's own making ({causes}), above {100 * WARN_RATE:g} %: "
            f"this run cannot tell modelled losses of that size from the testbed's"
        )
        if cpu_steal:
            warning += (
                f"; the hypervisor took {100 * cpu_steal:.1f} % of this machine's CPU meanwhile "
                "(steal): its stalls count as misses"
            )
    return {
        "deadline_misses": misses,
        "modelled_losses": {
            "total": modelled,
            "dropped": dropped,
            "delayed_past_deadline": got.modelled_late,
        },
        "delivered_in_time": got.in_time,
        "unaccounted": sent - modelled - got.misses - got.in_time,
        "deadline_miss_rate": rate,
        "deadline_warning": warning,
    }
