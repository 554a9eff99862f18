"""The agents' states as the launcher's observer reads them: the fields it keeps, nothing more.

A pool's bundle is read whole into arrays when every part is plainly a state of its own agent
(:func:`read_bundle`, msgspec, strict); anything doubtful is read part by part
(:func:`read_state`, orjson, lenient as a reader of one state), so what is kept and what is
counted as malformed do not depend on which path read it.
"""

from __future__ import annotations

from typing import NamedTuple

import msgspec
import numpy as np
import numpy.typing as npt
import orjson


class ObservedState(NamedTuple):
    """Agent ``agent``'s state of ``epoch``: its position [m], the values it used for lost
    neighbours at the epoch before (neighbour, x̃) and how many of them fell back."""

    epoch: int
    agent: int
    seq: int
    position: list[float]
    substituted: list[tuple[int, list[float]]]
    fell_back: int


class StateRows(NamedTuple):
    """A bundle's states as columns, row ``r`` its ``r``-th part's; every agent once."""

    epoch: npt.NDArray[np.int64]  # (m,)
    agent: npt.NDArray[np.int64]  # (m,)
    seq: npt.NDArray[np.int64]  # (m,)
    position: npt.NDArray[np.float64]  # (m, d) [m]
    substituted: list[list[tuple[int, list[float]]]]  # per row: (neighbour, x̃)
    fell_back: npt.NDArray[np.int64]  # (m,) substituted values that fell back


class _Part(msgspec.Struct, gc=False):
    agent: int
    message: str


class _Bundle(msgspec.Struct, gc=False):
    parts: list[_Part]


class _Substitute(msgspec.Struct, gc=False):
    neighbour: int
    value: list[float]
    fallback: bool = False


class _State(msgspec.Struct, gc=False):  # unknown fields skipped: only these are kept
    epoch: int
    agent: int
    seq: int
    position: list[float]
    substituted: list[_Substitute]


_BUNDLE = msgspec.json.Decoder(_Bundle)
_STATE = msgspec.json.Decoder(_State)


class Bounds(NamedTuple):
    """What a state of the run may hold: epochs 0..``epochs``, agents 1..``n``, ``dimension``."""

    epochs: int
    n: int
    dimension: int


def read_bundle(payload: bytes, first: int, bounds: Bounds) -> StateRows | None:
    """Every part of a pool's bundle (its key's first agent ``first``) at once; None unless
    each part is a state of its own agent, in ``bounds``, and no agent comes twice."""
    try:
        parts = _BUNDLE.decode(payload).parts
        decode = _STATE.decode
        states = [decode(p.message) for p in parts]  # each alone: no part spills into another
        owners = np.array([p.agent for p in parts], dtype=np.int64)
        epoch = np.array([s.epoch for s in states], dtype=np.int64)
        agent = np.array([s.agent for s in states], dtype=np.int64)
        seq = np.array([s.seq for s in states], dtype=np.int64)
        position = np.array([s.position for s in states], dtype=np.float64)
    except (msgspec.DecodeError, OverflowError, ValueError):  # ragged positions: ValueError
        return None
    m = len(states)
    if m == 0 or position.shape != (m, bounds.dimension):
        return None
    ok = (epoch >= 0) & (epoch <= bounds.epochs) & (agent >= 1) & (agent <= bounds.n)
    ok &= (agent == owners) & (owners >= first)
    if not ok.all() or len(np.unique(agent)) != m:
        return None
    substituted = [[(s.neighbour, s.value) for s in st.substituted] for st in states]
    fell_back = np.array([sum(s.fallback for s in st.substituted) for st in states], dtype=np.int64)
    return StateRows(epoch, agent, seq, position, substituted, fell_back)


def read_state(payload: bytes | str, owner: str, bounds: Bounds) -> ObservedState | None:
    """One state; None unless it is plainly agent ``owner``'s (the id its key, or its part of
    a pool's bundle, stands for) and in ``bounds``."""
    try:
        msg = orjson.loads(payload)
        k, i, seq = int(msg["epoch"]), int(msg["agent"]), int(msg["seq"])
        position = [float(v) for v in msg["position"]]
        subs = [(int(s["neighbour"]), [float(v) for v in s["value"]]) for s in msg["substituted"]]
        fell = sum(bool(s.get("fallback")) for s in msg["substituted"])
        ok = 0 <= k <= bounds.epochs and 1 <= i <= bounds.n
        ok = ok and len(position) == bounds.dimension and str(i) == owner
    except (orjson.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError):
        return None
    return ObservedState(k, i, seq, position, subs, fell) if ok else None


def read_parts(payload: bytes, first: int) -> list[tuple[int, str]] | None:
    """A bundle's parts as (agent, message), to read one by one; None if it is no bundle."""
    try:
        parts = orjson.loads(payload)["parts"]
        return [(int(p["agent"]), str(p["message"])) for p in parts]
    except (orjson.JSONDecodeError, KeyError, TypeError, ValueError):
        return None


__all__ = ["Bounds", "ObservedState", "StateRows", "read_bundle", "read_parts", "read_state"]
