"""The run's log lines as ``foxglove.Log``: what the processes say in their statuses, netem's link changes.

A process's change of state (``ready``, ``done``, ``error``) is a line, and so is a status
with a detail (netem's team events, the final counts with their deadline misses) or with
malformed payloads; a bare ``running`` progress status is not. Levels: ``error`` state ERROR, malformed payloads WARNING, the rest INFO. The
log's name is the sender (``netem``, ``agent/3``, ...). Pure: messages in, the SDK's
``Log`` out.
"""

from __future__ import annotations

import json

from foxglove.messages import Log, LogLevel

from formation.messages import LinkChange, Status
from recorder.live.scene import timestamp


def status_log(status: Status, stamp_ns: int) -> Log | None:
    """The line of ``status`` received at ``stamp_ns`` [ns], or None for a bare progress status."""
    if status.state == "running" and not status.detail and not status.malformed:
        return None
    level = LogLevel.Info
    text = status.state + (f": {status.detail}" if status.detail else "")
    if status.malformed:
        level = LogLevel.Warning
        text += f"; malformed payloads {json.dumps(status.malformed, sort_keys=True)}"
    if status.state == "error":
        level = LogLevel.Error
    return Log(timestamp=timestamp(stamp_ns), level=level, message=text, name=status.sender)


def change_log(change: LinkChange, stamp_ns: int) -> Log:
    """The line of netem's accepted change of a link's models, received at ``stamp_ns`` [ns]."""
    models = json.dumps(change.models, sort_keys=True, default=str)
    text = (
        f"link {change.source}->{change.target} ({change.link_class}) from epoch "
        f"{change.from_epoch}: {models}"
    )
    return Log(timestamp=timestamp(stamp_ns), level=LogLevel.Info, message=text, name=change.sender)


__all__ = ["change_log", "status_log"]
