"""Bundles in a recording: several agents' messages in one, each part checked by the trust gate
as if it came alone on its agent's key.

The leader's estimate parts and a pool's reports are trusted or skipped whole; a pool's states,
the run's true positions, part by part: a forged or malformed part is counted on the bundle's
channel and skipped, and the others stay.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from typing import Any, Protocol

from msgspec import Struct
from pydantic import ValidationError

from formation import keys
from formation.messages import AgentEstimate, Bundle, BundlePart, CoordinationState, TokenReport
from recorder.reading.bulk import plain
from recorder.reading.skips import FORGED, INVALID, Skip, Skipped


class Gate(Protocol):
    """What a bundle's parts are checked by: :class:`recorder.reading.trust.Gate`'s checks of a
    message on its agent's own key."""

    plain_bulk: bool
    conflicts: bool
    skipped: Skipped
    passed: Counter[str]

    def _sender(self, msg: Any, owner: str) -> None: ...
    def _agent_part(self, msg: AgentEstimate, i: int) -> None: ...
    def _report(self, msg: TokenReport, i: int) -> None: ...
    def _state(self, msg: CoordinationState, i: int) -> None: ...
    def _first(self, topic: str, epoch: int, data: bytes) -> None: ...
    def _key_id(self, part: str) -> int: ...


class StateParts(Struct, frozen=True):
    """The trusted states of a pool's bundle (models, or structs with ``plain_bulk``)."""

    epoch: int
    states: list[Any]


def _inner(model: Any, part: BundlePart) -> Any:
    try:
        return model.model_validate_json(part.message)
    except (ValidationError, ValueError) as exc:
        detail = str(exc).splitlines()[0]
        raise Skip(INVALID, f"agent {part.agent}'s part: {detail}") from None


def estimate_bundle(gate: Gate, msg: Bundle, topic: str) -> None:
    """The leader's parts in one message: each checked as if it came on its own key."""
    gate._sender(msg, "leader")
    if msg.phase != "estimate":
        raise Skip(FORGED, f"a bundle of {msg.phase}s on the leader's estimates' key")
    for part in msg.parts:
        inner = _inner(AgentEstimate, part)
        if inner.seq != part.seq or inner.epoch != msg.epoch:
            raise Skip(FORGED, f"agent {part.agent}'s part of another seq or epoch")
        gate._agent_part(inner, part.agent)


def _pool(gate: Gate, msg: Bundle, topic: str, phase: str) -> int:
    """The pool whose key ``topic`` is, once ``msg`` is a bundle of ``phase`` its pool sent."""
    args = keys.parse(topic).args
    pool = gate._key_id(args[0])
    if msg.phase != phase or (len(args) > 1 and args[1] != phase):
        raise Skip(FORGED, f"a bundle of {msg.phase}s on a {phase} key of pool {pool}")
    if msg.sender != f"pool/{pool}":
        raise Skip(FORGED, f"sender {msg.sender!r} on a key of pool {pool}")
    return pool


def report_bundle(gate: Gate, msg: Bundle, topic: str) -> None:
    """A pool's reports in one message: each checked as if it came on its agent's key."""
    pool = _pool(gate, msg, topic, "report")
    for part in msg.parts:
        inner = _inner(TokenReport, part)
        if inner.seq != part.seq or inner.epoch != msg.epoch or part.agent < pool:
            raise Skip(FORGED, f"agent {part.agent}'s part of another seq, epoch or pool")
        gate._report(inner, part.agent)


def state_bundle(gate: Gate, msg: Bundle, topic: str) -> StateParts:
    """A pool's states in one message: each part checked as if it came on its agent's key
    (a contradiction of an earlier state of that key and epoch included); a part that fails
    is counted on ``topic`` and left out."""
    pool = _pool(gate, msg, topic, "state")
    run_id = keys.parse(topic).run_id
    states = []
    for part in msg.parts:
        try:
            data = part.message.encode()
            inner: Any = plain("agent_state", data) if gate.plain_bulk else None
            inner = _inner(CoordinationState, part) if inner is None else inner
            if inner.seq != part.seq or inner.epoch != msg.epoch or part.agent < pool:
                raise Skip(FORGED, f"agent {part.agent}'s part of another seq, epoch or pool")
            gate._state(inner, part.agent)
            if gate.conflicts and inner.epoch >= 0:
                gate._first(keys.agent_state(run_id, part.agent), inner.epoch, data)
        except Skip as skip:
            gate.skipped.add(topic, skip.reason, f"agent {part.agent}'s part: {skip}")
            continue
        states.append(inner)
    gate.passed["agent_state"] += len(states)
    return StateParts(msg.epoch, states)


# By channel kind (recorder.recording.schemas); a check that returns parts passes those.
BUNDLE_CHECKS: dict[str, Callable[[Gate, Bundle, str], StateParts | None]] = {
    "estimate_bundle": estimate_bundle,
    "pool_bundle": report_bundle,
    "state_bundle": state_bundle,
}

__all__ = ["BUNDLE_CHECKS", "StateParts", "estimate_bundle", "report_bundle", "state_bundle"]
