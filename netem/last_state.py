"""What a restarted agent takes back: the last state netem handled of it."""

from __future__ import annotations

from typing import Any

import orjson


def state_of(last: tuple[int, Any] | None) -> dict[str, Any] | None:
    """The epoch, position and (a unicycle's) heading of a state packet netem handled (its
    payload, unparsed)."""
    if last is None:
        return None
    epoch, payload = last
    raw = payload if isinstance(payload, bytes) else payload.to_bytes()
    try:
        state = orjson.loads(raw)
        position = [float(v) for v in state["position"]]
        heading = None if state.get("heading") is None else float(state["heading"])
    except (orjson.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError):
        return None  # a malformed last packet: the agent starts from the scenario's position
    return {"epoch": epoch, "position": position, "heading": heading}


__all__ = ["state_of"]
