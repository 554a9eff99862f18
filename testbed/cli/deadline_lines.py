"""``formation run --mode realtime``: modelled losses and deadline misses, apart, in the summary."""

from __future__ import annotations

from typing import Any


def _pct(n: int, sent: int) -> str:
    return f"{n} ({100 * n / sent:.2f} %)" if sent else str(n)


def deadline_cells(summary: dict[str, Any]) -> list[str]:
    """The summary table's two realtime cells: modelled losses, deadline misses."""
    if "deadline_misses" not in summary:
        return ["-", "-"]
    sent = summary["packets_sent"]
    return [
        _pct(summary["modelled_losses"]["total"], sent),
        _pct(summary["deadline_misses"]["total"], sent),
    ]


def deadline_notes(strategy: str, summary: dict[str, Any]) -> list[str]:
    """The misses by cause, the packets unaccounted for, and the warning above 0.1 %."""
    if "deadline_misses" not in summary:
        return []
    by_cause = ", ".join(f"{c} {n}" for c, n in summary["deadline_misses"]["by_cause"].items())
    lines = [f"{strategy}: deadline misses by cause: {by_cause}"]
    if summary.get("priorities"):
        lines.append(f"{strategy}: {summary['priorities']}")
    if summary.get("robot_silent"):
        lines.append(
            f"{strategy}: {summary['robot_silent']} packets late or never taken as agents "
            "waited for their robots' poses (robot silent): the robots', not the testbed's misses"
        )
    if summary["unaccounted"]:
        lines.append(
            f"{strategy}: {summary['unaccounted']} packets unaccounted for "
            "(neither modelled losses, nor misses, nor delivered in time)"
        )
    if summary["deadline_warning"]:
        lines.append(f"{strategy}: {summary['deadline_warning']}")
    return lines
