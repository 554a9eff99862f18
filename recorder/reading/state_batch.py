"""A chunk's agent states judged at once: one decode each, the trust gate's checks as arrays.

A recording of 10,000 agents holds a million states; the gate's checks one state at a time
were most of the cost of reading it. :func:`judge_states` decodes a chunk's states with
msgspec (:mod:`recorder.reading.bulk`) and runs over the whole batch what
:meth:`~recorder.reading.trust.Gate.check` runs on one agent state: the sender owns the key,
the agent id, epoch and substituted neighbours exist, every vector has the scenario's
dimension and is finite, a key and epoch seen before carries the same payload. It only
vouches: when any state of the batch is not plainly good it returns None, and the caller
sends the chunk through the gate message by message, which counts each skip with its
reason as before.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from itertools import chain
from operator import attrgetter, ne
from typing import Any

import msgspec
import numpy as np
import numpy.typing as npt

from formation import keys
from recorder.reading.bulk import DECODERS
from recorder.reading.trust import Gate
from recorder.reading.value_checks import rows_of

Array = npt.NDArray[np.float64]
Ints = npt.NDArray[np.int64]
Bools = npt.NDArray[np.bool_]

_STATE = "agent_state"
_NO_ID = -1


@dataclass(frozen=True)
class StateBlock:
    """Trusted agent states, one row each (N,), and their substitutions (M,).

    heading : [rad], NaN where none; saturated : −1 where none; sub_state : the row of the
    state each substitution came with; sub_value : (M, d) [m]
    """

    epoch: Ints
    agent: Ints
    position: Array
    heading: Array
    saturated: Ints
    sub_state: Ints
    sub_neighbour: Ints
    sub_fallback: Bools
    sub_value: Array

    @classmethod
    def of_rows(cls, rows: list[Any], d: int) -> StateBlock:
        """From trusted states (models or structs), in order."""
        subs = [(r, s) for r, state in enumerate(rows) for s in state.substituted]
        values = [s.value for _, s in subs]
        return cls(
            epoch=np.array([s.epoch for s in rows], dtype=np.int64),
            agent=np.array([s.agent for s in rows], dtype=np.int64),
            position=np.array([s.position for s in rows], dtype=float).reshape(-1, d),
            heading=np.array(
                [np.nan if s.heading is None else s.heading for s in rows], dtype=float
            ),
            saturated=np.array(
                [-1 if s.saturated is None else s.saturated for s in rows], dtype=np.int64
            ),
            sub_state=np.array([r for r, _ in subs], dtype=np.int64),
            sub_neighbour=np.array([s.neighbour for _, s in subs], dtype=np.int64),
            sub_fallback=np.array([s.fallback for _, s in subs], dtype=bool),
            sub_value=np.array(values, dtype=float).reshape(-1, d),
        )


@lru_cache(maxsize=1 << 16)
def _owner(topic: str) -> int:
    """The agent whose state key ``topic`` is, or −1."""
    parsed = keys.parse(topic)
    if parsed.kind != keys.agent_state.__name__:
        return _NO_ID
    try:
        agent = int(parsed.args[0])
    except ValueError:
        return _NO_ID
    return agent if 0 < agent < 2**62 else _NO_ID


@lru_cache(maxsize=1 << 16)
def _sender(agent: int) -> str:
    return f"agent/{agent}"


def _ints(values: Any, count: int) -> Ints | None:
    try:
        return np.fromiter(values, np.int64, count)
    except OverflowError:  # past 63 bits: the gate's own path says what it is
        return None


def _finite_rows(rows: list[Any], d: int) -> Array | None:
    """``rows`` as an (N, d) array if each has d finite components, else None."""
    arr = rows_of(rows, (d,))
    if arr is None or not np.isfinite(arr).all():  # ragged, not numbers or not finite
        return None
    return arr


def judge_states(
    gate: Gate,
    topics: list[str],
    datas: list[bytes],
    claims: tuple[list[int], list[int]] | None = None,
) -> StateBlock | None:
    """The states ``datas`` on ``topics`` (agent state keys) as a block if the gate would pass
    every one of them, counted as passed; else None, with nothing counted or remembered.
    ``claims``: the seq and epoch each state must carry (a bundle's part's)."""
    s, count = gate.scenario, len(datas)
    if s is None or not count:
        return None
    n, d = s.n, s.dimension
    try:
        msgs = list(map(DECODERS[_STATE].decode, datas))
    except msgspec.DecodeError:  # ValidationError too
        return None
    owner = np.fromiter(map(_owner, topics), np.int64, count)
    agent = _ints(map(attrgetter("agent"), msgs), count)
    epoch = _ints(map(attrgetter("epoch"), msgs), count)
    if agent is None or epoch is None:
        return None
    if claims is not None and not _as_claimed(msgs, epoch, claims):
        return None
    if not (((owner >= 1) & (owner <= n) & (agent == owner)).all() and epoch.max() <= gate.epochs):
        return None  # the model checks epoch ≥ −1; the gate wants ≥ 0 below
    if epoch.min() < 0 or not _owned(msgs, owner):
        return None
    position = _finite_rows(list(map(attrgetter("position"), msgs)), d)
    velocity = [v for v in map(attrgetter("velocity"), msgs) if v is not None]
    if position is None or (velocity and _finite_rows(velocity, d) is None):
        return None
    subs = _substitutions(gate, msgs, owner)
    if subs is None or (gate.conflicts and not _first(gate, topics, epoch, datas)):
        return None
    headings = list(map(attrgetter("heading"), msgs))
    saturated = list(map(attrgetter("saturated"), msgs))
    gate.passed[_STATE] += count
    return StateBlock(
        epoch,
        agent,
        position,
        np.full(count, np.nan)
        if headings.count(None) == count
        else np.array([np.nan if h is None else h for h in headings], dtype=float),
        np.full(count, -1, dtype=np.int64)
        if saturated.count(None) == count
        else np.array([-1 if v is None else v for v in saturated], dtype=np.int64),
        *subs,
    )


def judge_bundles(gate: Gate, topics: list[str], datas: list[bytes]) -> StateBlock | None:
    """The parts of the pools' state bundles ``datas`` on ``topics`` (``agent/pool/<p>/state``)
    as a block if the gate would pass each bundle and every part of it as if it came alone
    (:func:`recorder.reading.bundle_checks.state_bundle`), counted as passed; else None, with
    nothing counted or remembered."""
    part_topics: list[str] = []
    part_datas: list[bytes] = []
    seqs: list[int] = []
    epochs: list[int] = []
    decode = DECODERS["state_bundle"].decode
    for topic, data in zip(topics, datas, strict=True):
        parsed = keys.parse(topic)
        try:
            bundle = decode(data)
        except msgspec.DecodeError:
            return None
        pool = parsed.args[0]
        if bundle.phase != "state" or bundle.sender != f"pool/{pool}" or not pool.isdigit():
            return None
        first = int(pool)
        for part in bundle.parts:
            if part.agent < first:
                return None
            part_topics.append(_state_key(parsed.run_id, part.agent))
            part_datas.append(part.message.encode())
            seqs.append(part.seq)
            epochs.append(bundle.epoch)
    block = judge_states(gate, part_topics, part_datas, (seqs, epochs))
    if block is not None:
        gate.passed["state_bundle"] += len(datas)
    return block


@lru_cache(maxsize=1 << 16)
def _state_key(run_id: str, agent: int) -> str:
    return keys.agent_state(run_id, agent)


def _as_claimed(msgs: list[Any], epoch: Ints, claims: tuple[list[int], list[int]]) -> bool:
    seq = _ints(map(attrgetter("seq"), msgs), len(msgs))
    return seq is not None and seq.tolist() == claims[0] and epoch.tolist() == claims[1]


def _owned(msgs: list[Any], owner: Ints) -> bool:
    """Each sender owns its key: ``agent/<i>``, or a pool ``pool/<a>`` with ``a ≤ i``."""
    senders = list(map(attrgetter("sender"), msgs))
    wanted = list(map(_sender, owner.tolist()))
    if senders == wanted:
        return True
    return all(
        Gate.owned_by_agent(got, int(i))
        for got, want, i in zip(senders, wanted, owner, strict=True)
        if got != want
    )


def _substitutions(
    gate: Gate, msgs: list[Any], owner: Ints
) -> tuple[Ints, Ints, Bools, Array] | None:
    """The substituted values of ``msgs`` as arrays, if each has a neighbour with a
    formation link into its agent and a finite value of the scenario's dimension."""
    lists = list(map(attrgetter("substituted"), msgs))
    sizes = np.fromiter(map(len, lists), np.int64, len(lists))
    total, d, n = int(sizes.sum()), gate.d, gate.n
    if not total:
        return (
            np.zeros(0, dtype=np.int64),
            np.zeros(0, dtype=np.int64),
            np.zeros(0, dtype=bool),
            np.zeros((0, d)),
        )
    flat = list(chain.from_iterable(lists))
    neighbour = _ints(map(attrgetter("neighbour"), flat), total)
    values = _finite_rows(list(map(attrgetter("value"), flat)), d)
    if neighbour is None or values is None:
        return None
    state = np.repeat(np.arange(len(msgs), dtype=np.int64), sizes)
    if not gate.within_links(neighbour * (n + 1) + owner[state]):  # and so 1 ≤ neighbour ≤ n
        return None
    fallback = np.fromiter(map(attrgetter("fallback"), flat), bool, total)
    return state, neighbour, fallback, values


def _first(gate: Gate, topics: list[str], epoch: Ints, datas: list[bytes]) -> bool:
    """No state contradicts an earlier one of its key and epoch (nor one in the batch, which
    the gate's own path sorts out); if so, the batch's are remembered."""
    digests = list(map(hash, datas))
    at = list(zip(topics, epoch.tolist(), strict=True))
    new = dict(zip(at, digests, strict=True))
    seen = gate.seen
    if len(new) != len(at) or any(map(ne, map(seen.get, at, digests), digests)):
        return False
    seen.update(new)
    return True


__all__ = ["StateBlock", "judge_bundles", "judge_states"]
