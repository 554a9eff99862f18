"""The report's realtime section: modelled losses and deadline misses, apart.

``formation run --mode realtime`` writes the run's accounting (``formation.deadlines``,
in testbed's outcome summary) as ``deadlines.json`` beside the recording
(:func:`write_deadlines`); a report of that recording reads it back. A file that does
not hold the expected numbers is skipped with a note, never trusted.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from formation.deadlines import CAUSES, WARN_RATE, over_warn_rate

FILE = "deadlines.json"
KEYS = (
    "packets_sent",
    "modelled_losses",
    "deadline_misses",
    "delivered_in_time",
    "unaccounted",
    "robot_silent",
    "deadline_miss_rate",
    "cpu_steal",
)


def write_deadlines(run_dir: Path, summary: dict[str, Any]) -> None:
    """A realtime run's accounting (its summary's :data:`KEYS`) as :data:`FILE` in ``run_dir``;
    nothing for a lockstep run (no misses counted)."""
    if "deadline_misses" in summary:
        text = json.dumps({k: summary[k] for k in KEYS}, indent=2) + "\n"
        (run_dir / FILE).write_text(text, encoding="utf-8")


def read_deadlines(run_dir: Path) -> dict[str, Any] | None:
    """The accounting beside a recording: None if absent; ``{"unreadable": why}`` if bad."""
    path = run_dir / FILE
    if not path.exists():
        return None
    try:
        got = json.loads(path.read_text(encoding="utf-8"))
        misses = got["deadline_misses"]
        return {
            "sent": int(got["packets_sent"]),
            "modelled": int(got["modelled_losses"]["total"]),
            "delayed_past_deadline": int(got["modelled_losses"]["delayed_past_deadline"]),
            "misses": int(misses["total"]),
            "by_cause": {c: int(misses["by_cause"][c]) for c in CAUSES},
            "in_time": int(got["delivered_in_time"]),
            "robot_silent": int(got.get("robot_silent") or 0),
            "cpu_steal": None if got.get("cpu_steal") is None else float(got["cpu_steal"]),
        }
    except (OSError, ValueError, TypeError, KeyError) as exc:
        return {"unreadable": f"{path}: {type(exc).__name__}: {exc}"}


def deadline_lines(label: str, d: dict[str, Any]) -> list[str]:
    """Markdown lines for one run's accounting (:func:`read_deadlines`)."""
    if "unreadable" in d:
        return [f"- {label}: the deadline accounting was skipped, not trusted ({d['unreadable']})"]
    sent = d["sent"] or 1

    def pct(n: int) -> str:
        return f"{n} ({100 * n / sent:.2f} %)"

    causes = ", ".join(f"{c} {n}" for c, n in d["by_cause"].items())
    lines = [
        f"- {label}: {d['sent']} packets sent; modelled losses {pct(d['modelled'])} "
        f"(of which delayed past the deadline by the link model {d['delayed_past_deadline']}); "
        f"deadline misses of the testbed's own making {pct(d['misses'])} ({causes}); "
        f"delivered in time {pct(d['in_time'])}"
    ]
    if d.get("robot_silent"):
        lines.append(
            f"- {label}: late or never taken as agents waited for their robots' poses (robot "
            f"silent, not counted as misses): {pct(d['robot_silent'])}"
        )
    if over_warn_rate(d["misses"], d["sent"]):
        lines.append(
            f"- **warning** ({label}): deadline misses exceed {100 * WARN_RATE:g} % of the "
            "packets; this run cannot tell modelled losses of that size from the testbed's own"
            + (
                f"; the hypervisor took {100 * d['cpu_steal']:.1f} % of the machine's CPU "
                "meanwhile (steal)"
                if d.get("cpu_steal")
                else ""
            )
        )
    return lines
