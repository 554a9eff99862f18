"""An agent set's messages as JSON, from columns: each agent's state and report, and a pool's
:class:`~formation.messages.Bundle` of them. A pool of hundreds sends one of each per agent and
epoch; they are made from byte templates and orjson's arrays, with no model and no dict per
message. Each equals what its wire model (:mod:`formation.messages`) validates.

A bundle carries each message as a JSON string: made ``quoted``, a message is that string's
inside from the start (its templates escaped once), so the bundle wraps it as it is."""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from functools import lru_cache
from itertools import chain, repeat

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
_TOKEN_1, _TOKEN_0 = quoted(b'1,"z":['), quoted(b'0,"z":null}')  # a link's token and z


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
    state = _FORMS[_STATE][in_string]
    tail = _FORMS[_SILENT][in_string] if robot_silent else b"}"
    listed, pose = _state_fields(substituted, poses, in_string)
    return [
        head % (seqs[n], epoch, stamp_ns) + state % (i, position, listed[n], pose[n], tail)
        for n, (i, position) in enumerate(zip(agents, rows_json(positions), strict=True))
    ]


def states_bundle(
    head: bytes,
    seq: int,
    epoch: int,
    stamp_ns: int,
    agents: Sequence[int],
    seqs: Sequence[int],
    positions: Array,
    substituted: Sequence[Substituted],
    poses: Sequence[tuple[float, int]] | None = None,
    robot_silent: bool = False,
) -> bytes:
    """The :class:`~formation.messages.Bundle` of :func:`state_messages` (the same bytes as
    :func:`bundle_message` makes of them), in one format of a form made once per agent set."""
    form = _states_form(head, tuple(agents), robot_silent)
    listed, pose = _state_fields(substituted, poses, True)
    rows, k, t = rows_json(positions), repeat(epoch), repeat(stamp_ns)
    # strict=False: repeat never ends; the seqs, the rows and the fields end together
    args = chain.from_iterable(zip(seqs, seqs, k, t, rows, listed, pose, strict=False))
    return _bundle(head, seq, epoch, stamp_ns, "state", form % tuple(args))


@lru_cache(maxsize=8)
def _states_form(head: bytes, agents: tuple[int, ...], robot_silent: bool) -> bytes:
    """The parts of a bundle of ``agents``' states as one form: per part its seq, the
    header's, the position, ``substituted`` and the pose fields."""
    tail = _FORMS[_SILENT][True] if robot_silent else b"}"
    state = _FORMS[_STATE][True]
    return b",".join(_part_form(i, head, state % (i, b"%b", b"%b", b"%b", tail)) for i in agents)


def _state_fields(
    substituted: Sequence[Substituted], poses: Sequence[tuple[float, int]] | None, in_string: bool
) -> tuple[list[bytes], list[bytes]]:
    """Each state's ``substituted`` list and its pose's fields (empty for point agents)."""
    listed = [
        _EMPTY
        if not subs
        else _maybe_quoted(
            orjson.dumps([{"neighbour": j, "value": v, "fallback": f} for j, v, f in subs]),
            in_string,
        )
        for subs in substituted
    ]
    if poses is None:
        return listed, [b""] * len(listed)
    pose_form = _FORMS[_POSE][in_string]
    return listed, [pose_form % _pose(p) for p in poses]


def _maybe_quoted(text: bytes, in_string: bool) -> bytes:
    return quoted(text) if in_string else text


def _part_form(agent: int, head: bytes, body: bytes) -> bytes:
    """A bundle's part of ``agent`` as a form: ``%d`` for the part's seq, then ``head``'s
    slots (seq, epoch, stamp) and ``body``'s, the message made :func:`quoted`."""
    return b'{"agent":%d,"seq":%%d,"message":"' % agent + quoted(head) + body + b'"}'


def _bundle(head: bytes, seq: int, epoch: int, stamp_ns: int, phase: str, parts: bytes) -> bytes:
    return head % (seq, epoch, stamp_ns) + b',"kind":"bundle","phase":%b,"parts":[%b]}' % (
        orjson.dumps(phase),
        parts,
    )


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
        self._order = np.array(
            sorted(range(len(receivers)), key=lambda link: row[receivers[link]]), dtype=np.int64
        )
        counts = [0] * len(self.agents)
        for i in receivers:
            counts[row[i]] += 1
        self._ends = list(itertools.accumulate(counts))
        by_agent = [senders[link] for link in self._order.tolist()]
        arrived = [b'{"neighbour":%d,"token":1,"z":[' % j for j in by_agent]
        lost = [b'{"neighbour":%d,"token":0,"z":null}' % j for j in by_agent]
        self._items = {  # each link's item before its z, and when lost; plain, quoted
            False: (arrived, lost),
            True: ([quoted(b) for b in arrived], [quoted(b) for b in lost]),
        }
        self._by_agent = by_agent
        self._forms: dict[tuple[bytes, bool, bool], bytes] = {}  # bundle forms, made as needed

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

    def bundle(
        self,
        head: bytes,
        seq: int,
        epoch: int,
        stamp_ns: int,
        seqs: Sequence[int],
        arrived: npt.NDArray[np.bool_],
        z: Array,
        robot_silent: bool = False,
    ) -> bytes:
        """The :class:`~formation.messages.Bundle` of :meth:`messages` (the same bytes as
        :func:`bundle_message` makes of them), in one format of a form made once."""
        order = self._order
        slots = rows_json(z[order])
        every = bool(arrived.all())
        if not every:  # the form leaves each link's token and z to its slot
            slots = [
                _TOKEN_1 + v + b"]}" if a else _TOKEN_0
                for v, a in zip(slots, arrived[order].tolist(), strict=True)
            ]
        args: list[bytes | int] = []
        start = 0
        for n, end in enumerate(self._ends):
            args += (seqs[n], seqs[n], epoch, stamp_ns)
            args += slots[start:end]
            start = end
        parts = self._form(head, every, robot_silent) % tuple(args)
        return _bundle(head, seq, epoch, stamp_ns, "report", parts)

    def _form(self, head: bytes, every: bool, robot_silent: bool) -> bytes:
        """The bundle's parts as one form: per part its seq, the header's, then per link its
        z (``every`` link arrived) or its token and z."""
        form = self._forms.get((head, every, robot_silent))
        if form is None:
            item = b'{"neighbour":%d,"token":1,"z":[' if every else b'{"neighbour":%d,"token":'
            close = b"%b]}" if every else b"%b"
            items = [quoted(item % j) + close for j in self._by_agent]
            report = _FORMS[_REPORT][True]
            tail = _FORMS[_SILENT][True] if robot_silent else b"}"
            parts, start = [], 0
            for i, end in zip(self.agents, self._ends, strict=True):
                joined = b",".join(items[start:end])
                parts.append(_part_form(i, head, report % (i, joined, tail)))
                start = end
            form = self._forms[(head, every, robot_silent)] = b",".join(parts)
        return form


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
    return _bundle(head, seq, epoch, stamp_ns, phase, parts)
