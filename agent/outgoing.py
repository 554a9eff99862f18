"""An agent set's messages as JSON, from columns: each agent's state and report, and a pool's
:class:`~formation.messages.Bundle` of them. A pool of hundreds sends one of each per agent and
epoch; they are made from byte templates and orjson's arrays, with no model and no dict per
message. Each equals what its wire model (:mod:`formation.messages`) validates.

A bundle carries each message as a JSON string: made ``quoted``, a message is that string's
inside from the start (its templates escaped once), so the bundle wraps it as it is."""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
import orjson

Array = npt.NDArray[np.float64]
Substituted = list[tuple[int, list[float], bool]]  # (neighbour, x̃_j, fallback) per lost link

_EMPTY = b"[]"


def quoted(text: bytes) -> bytes:
    """JSON ``text`` (no raw control character, as orjson writes it) as a JSON string's inside."""
    return text.replace(b"\\", b"\\\\").replace(b'"', b'\\"')


_STATE = b',"kind":"state","agent":%d,"position":[%b],"velocity":null,"substituted":%b%b%b'
_POSE = b',"heading":%b,"saturated":%d'
_SILENT = b',"robot_silent":true}'
_REPORT = b',"kind":"report","agent":%d,"measurements":[%b]%b'
_FORMS = {t: (t, quoted(t)) for t in (_STATE, _POSE, _SILENT, _REPORT)}  # plain, quoted


def rows_json(values: Array) -> list[bytes]:
    """Each row of ``values`` (a, d) as the inside of a JSON array, from one orjson call."""
    text = orjson.dumps(np.ascontiguousarray(values), option=orjson.OPT_SERIALIZE_NUMPY)
    if text == _EMPTY:
        return []
    return text[2:-2].split(b"],[")


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
    in_string: bool = False,
) -> list[bytes]:
    """Each agent's :class:`~formation.messages.CoordinationState`: ``positions`` (a, d) [m];
    ``poses``: each unicycle's heading [rad] and saturated sub-steps (omitted for point
    agents); ``robot_silent``: sent late as the agents waited for their robots' poses;
    ``in_string``: made :func:`quoted`, for a bundle."""
    head = quoted(head) if in_string else head
    state, pose_form = _FORMS[_STATE][in_string], _FORMS[_POSE][in_string]
    tail = _FORMS[_SILENT][in_string] if robot_silent else b"}"
    out = []
    for n, (i, position) in enumerate(zip(agents, rows_json(positions), strict=True)):
        subs = substituted[n]
        listed = _EMPTY
        if subs:
            listed = orjson.dumps([{"neighbour": j, "value": v, "fallback": f} for j, v, f in subs])
            listed = quoted(listed) if in_string else listed
        pose = b"" if poses is None else pose_form % _pose(poses[n])
        out.append(head % (seqs[n], epoch, stamp_ns) + state % (i, position, listed, pose, tail))
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
        # the links by agent (in link order within each): agent n's are order[ends[n - 1]:ends[n]]
        self._order = sorted(range(len(receivers)), key=lambda link: row[receivers[link]])
        counts = [0] * len(self.agents)
        for i in receivers:
            counts[row[i]] += 1
        self._ends = list(itertools.accumulate(counts))
        by_agent = [senders[link] for link in self._order]
        arrived = [b'{"neighbour":%d,"token":1,"z":[' % j for j in by_agent]
        lost = [b'{"neighbour":%d,"token":0,"z":null}' % j for j in by_agent]
        self._items = {  # each link's item before its z, and when lost; plain, quoted
            False: (arrived, lost),
            True: ([quoted(b) for b in arrived], [quoted(b) for b in lost]),
        }

    def messages(
        self,
        head: bytes,
        seqs: Sequence[int],
        epoch: int,
        stamp_ns: int,
        arrived: npt.NDArray[np.bool_],
        z: Array,
        robot_silent: bool = False,
        in_string: bool = False,
    ) -> list[bytes]:
        """Each agent's :class:`~formation.messages.TokenReport`: per in-link the token and,
        where it ``arrived`` (L,), ``z_ij`` (L, d) [m]; ``in_string``: made :func:`quoted`."""
        order = self._order
        zs = rows_json(z[order])
        before, lost = self._items[in_string]
        items = [
            before[n] + zs[n] + b"]}" if a else lost[n]
            for n, a in enumerate(arrived[order].tolist())
        ]
        head = quoted(head) if in_string else head
        report = _FORMS[_REPORT][in_string]
        tail = _FORMS[_SILENT][in_string] if robot_silent else b"}"
        out, start = [], 0
        for n, (i, end) in enumerate(zip(self.agents, self._ends, strict=True)):
            joined = b",".join(items[start:end])
            out.append(head % (seqs[n], epoch, stamp_ns) + report % (i, joined, tail))
            start = end
        return out


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
    """A :class:`~formation.messages.Bundle` of ``phase``: each agent's message (made
    ``in_string``), with the seq of its own key."""
    parts = b",".join(
        [
            b'{"agent":%d,"seq":%d,"message":"%b"}' % part
            for part in zip(agents, seqs, messages, strict=True)
        ]
    )
    return head % (seq, epoch, stamp_ns) + b',"kind":"bundle","phase":%b,"parts":[%b]}' % (
        orjson.dumps(phase),
        parts,
    )
