"""An agent set's messages as JSON, from columns: each agent's state and report, and a pool's
:class:`~formation.messages.Bundle` of them. A pool of hundreds sends one of each per agent and
epoch; they are made from byte templates and orjson's arrays, with no model and no dict per
message. Each equals what its wire model (:mod:`formation.messages`) validates."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
import orjson

Array = npt.NDArray[np.float64]
Substituted = list[tuple[int, list[float], bool]]  # (neighbour, x̃_j, fallback) per lost link

_EMPTY = b"[]"


def rows_json(values: Array) -> list[bytes]:
    """Each row of ``values`` (a, d) as a JSON array, from one orjson call."""
    text = orjson.dumps(np.ascontiguousarray(values), option=orjson.OPT_SERIALIZE_NUMPY)
    if text == _EMPTY:
        return []
    return [b"[" + row + b"]" for row in text[2:-2].split(b"],[")]


def state_messages(
    head: bytes,
    seqs: Sequence[int],
    epoch: int,
    stamp_ns: int,
    agents: Sequence[int],
    positions: Array,
    substituted: Sequence[Substituted],
    poses: Sequence[tuple[float, int]] | None = None,
    robot_silent: bool = False,
) -> list[bytes]:
    """Each agent's :class:`~formation.messages.CoordinationState`: ``positions`` (a, d) [m];
    ``poses``: each unicycle's heading [rad] and saturated sub-steps (omitted for point
    agents); ``robot_silent``: sent late as the agents waited for their robots' poses."""
    tail = b',"robot_silent":true}' if robot_silent else b"}"
    out = []
    for n, (i, position) in enumerate(zip(agents, rows_json(positions), strict=True)):
        subs = substituted[n]
        listed = (
            orjson.dumps([{"neighbour": j, "value": v, "fallback": f} for j, v, f in subs])
            if subs
            else _EMPTY
        )
        pose = b"" if poses is None else b',"heading":%b,"saturated":%d' % _pose(poses[n])
        out.append(
            head % (seqs[n], epoch, stamp_ns)
            + b',"kind":"state","agent":%d,"position":%b,"velocity":null,"substituted":%b%b%b'
            % (i, position, listed, pose, tail)
        )
    return out


def _pose(pose: tuple[float, int]) -> tuple[bytes, int]:
    return orjson.dumps(float(pose[0])), int(pose[1])


class Reports:
    """The reports of a set of agents' in-links (docs/model.md §4), made from the epoch's
    tokens and measurements.

    receivers, senders : (L,) each in-link's agents, in the runner's link order.
    """

    def __init__(self, agents: Sequence[int], receivers: Sequence[int], senders: Sequence[int]):
        self.agents = list(agents)
        row = {i: r for r, i in enumerate(self.agents)}
        self._links: list[list[int]] = [[] for _ in self.agents]  # each agent's in-links
        for link, i in enumerate(receivers):
            self._links[row[i]].append(link)
        self._arrived = [b'{"neighbour":%d,"token":1,"z":' % j for j in senders]
        self._lost = [b'{"neighbour":%d,"token":0,"z":null}' % j for j in senders]

    def messages(
        self,
        head: bytes,
        seqs: Sequence[int],
        epoch: int,
        stamp_ns: int,
        arrived: npt.NDArray[np.bool_],
        z: Array,
        robot_silent: bool = False,
    ) -> list[bytes]:
        """Each agent's :class:`~formation.messages.TokenReport`: per in-link the token and,
        where it ``arrived`` (L,), ``z_ij`` (L, d) [m]."""
        zs = rows_json(z)
        items = [
            self._arrived[n] + zs[n] + b"}" if a else self._lost[n]
            for n, a in enumerate(arrived.tolist())
        ]
        tail = b',"robot_silent":true}' if robot_silent else b"}"
        return [
            head % (seqs[n], epoch, stamp_ns)
            + b',"kind":"report","agent":%d,"measurements":[%b]%b'
            % (i, b",".join([items[link] for link in self._links[n]]), tail)
            for n, i in enumerate(self.agents)
        ]


def bundle_message(
    head: bytes,
    seq: int,
    epoch: int,
    stamp_ns: int,
    phase: str,
    agents: Sequence[int],
    seqs: Sequence[int],
    messages: Sequence[bytes],
) -> bytes:
    """A :class:`~formation.messages.Bundle` of ``phase``: each agent's message, with the seq
    of its own key. A message (orjson's JSON: no raw control character) is a JSON string once
    its backslashes and quotes are escaped."""
    parts = b",".join(
        [
            b'{"agent":%d,"seq":%d,"message":"%b"}'
            % (i, s, m.replace(b"\\", b"\\\\").replace(b'"', b'\\"'))
            for i, s, m in zip(agents, seqs, messages, strict=True)
        ]
    )
    return head % (seq, epoch, stamp_ns) + b',"kind":"bundle","phase":%b,"parts":[%b]}' % (
        orjson.dumps(phase),
        parts,
    )
