"""``formation run`` with robot bodies: their tracking, their pose counts, and why a process was
lost, in words (docs/robots.md)."""

from __future__ import annotations

import signal
from pathlib import Path
from typing import Any


def robot_notes(
    strategy: str, summary: dict[str, Any], recorded: dict[str, Any] | None
) -> list[str]:
    """Each robot's tracking error (from the recording) and the agents' pose counts."""
    from analysis import robot_counts_line, tracking_lines  # here: --help loads no numerics

    tracking = (recorded or {}).get("tracking")
    lines = [f"{strategy}: {line}" for line in tracking_lines(tracking)] if tracking else []
    counts = (recorded or {}).get("robot_counts") or {
        k.removeprefix("body_"): v
        for k, v in summary.get("deadline", {}).items()
        if k.startswith("body_")
    }  # as recorded, else as the launcher saw the statuses (--no-record)
    if counts:
        lines.append(f"{strategy}: {robot_counts_line(counts)}")
    return lines


def loss_cause(run_dir: Path, name: str, code: int | None) -> str:
    """Why process ``name`` ended, in words: its log's error line where it wrote one."""
    from formation.body import BODY_LOST_EXIT
    from formation.plugin_api import PLUGIN_EXIT

    said = _error_line(run_dir / "logs" / f"{name}.log")
    if code == BODY_LOST_EXIT:
        return "its robot's pose stopped coming" + (f" ({said})" if said else "")
    if code == PLUGIN_EXIT:
        return "a plug-in failed" + (f" ({said})" if said else "")
    if code is not None and code < 0:
        return f"killed by {signal.Signals(-code).name}"
    return said or f"exit code {code}"


def _error_line(log: Path) -> str:
    try:
        lines = log.read_text(errors="replace").splitlines()[-40:]
    except OSError:
        return ""
    found = [line for line in lines if "body lost:" in line or ": error: " in line]
    return found[-1].split(": error: ", 1)[-1].removeprefix("agent: ") if found else ""


__all__ = ["loss_cause", "robot_notes"]
