"""The leader's messages: token reports in as arrays, the estimate and each agent's part out as JSON.

A leader of a thousand agents reads a thousand reports and writes a thousand parts an
epoch: reports become columns at once, and the parts (alone, or escaped inside one bundle)
are joined from pieces laid out once, each position's text written once an epoch for all
the parts and the whole estimate that carry it.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from itertools import chain
from operator import itemgetter
from typing import Any

import numpy as np
import numpy.typing as npt
import orjson

from formation.messages import TokenReport
from formation.scenario import Scenario
from leader.epoch import LeaderEpoch

__all__ = [
    "EstimateParts",
    "LinkIndex",
    "estimate_message",
    "position_rows",
    "reports_to_measurements",
]

NUMPY = orjson.OPT_SERIALIZE_NUMPY
Ids = Sequence[int] | npt.NDArray[np.int64]


class LinkIndex:
    """``(sender, receiver)`` → row of the scenario's directed links, for columns of pairs.

    links : (L, 2) ``(sender, receiver)`` agent ids, each pair once
    """

    def __init__(self, links: npt.NDArray[np.int64], n: int) -> None:
        self.base = n + 1  # ids are 1..n; anything else is no link
        # receiver-major: a delivery's reports come by agent, so the searches come nearly sorted
        pair = links[:, 1] * self.base + links[:, 0]
        self.order = np.argsort(pair, kind="stable")
        self.sorted = pair[self.order]

    def rows(self, senders: Ids, receivers: Ids) -> npt.NDArray[np.int64]:
        """The row of each pair, −1 where it is no link."""
        s, r = _ids(senders), _ids(receivers)
        inside = (s >= 0) & (s < self.base) & (r >= 0) & (r < self.base)
        pair = np.where(inside, r * self.base + s, -1)
        at = np.minimum(np.searchsorted(self.sorted, pair), max(self.sorted.size - 1, 0))
        found = inside & (self.sorted[at] == pair) if self.sorted.size else inside & False
        return np.where(found, self.order[at], -1)


def _ids(values: Ids) -> npt.NDArray[np.int64]:
    """Agent ids as int64; one past 64 bits (a valid message may carry any integer) as −1."""
    try:
        return np.asarray(values, dtype=np.int64)
    except OverflowError:
        return np.array([v if -(2**63) <= v < 2**63 else -1 for v in values], dtype=np.int64)


def reports_to_measurements(
    scenario: Scenario, reports: Iterable[TokenReport], index: LinkIndex | None = None
) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.float64]]:
    """Reports → ``known`` (L,) and ``z`` (L, d) in the scenario's directed-link order.

    A measurement counts when its token is 1 and it carries ``d`` coordinates on a link of
    the scenario; of two for one link the later is kept. ``index``: the scenario's
    :class:`LinkIndex`, built once by a caller that asks every epoch.
    """
    links, d = scenario.directed_links, scenario.dimension
    index = LinkIndex(links, scenario.n) if index is None else index
    senders: list[int] = []
    receivers: list[int] = []
    values: list[float] = []
    sender, receiver, value = senders.append, receivers.append, values.extend
    for report in reports:
        agent = report.agent
        for m in report.measurements:
            got = m.z
            if m.token == 1 and got is not None and len(got) == d:
                sender(m.neighbour)
                receiver(agent)
                value(got)
    known = np.zeros(len(links), dtype=bool)
    z = np.zeros((len(links), d))
    rows = index.rows(senders, receivers)
    on_link = np.flatnonzero(rows >= 0)
    if on_link.size == 0:
        return known, z
    if np.bincount(rows[on_link]).max() > 1:  # the later of two for one link wins
        on_link = on_link[on_link.size - 1 - np.unique(rows[on_link][::-1], return_index=True)[1]]
    known[rows[on_link]] = True
    z[rows[on_link]] = np.array(values, dtype=np.float64).reshape(-1, d)[on_link]
    return known, z


def position_rows(
    positions: npt.NDArray[np.float64], observable: npt.NDArray[np.bool_]
) -> list[bytes]:
    """Each agent's estimate as JSON (``null`` when unobservable), written once an epoch."""
    if positions.shape[0] == 0:
        return []
    text = orjson.dumps(np.ascontiguousarray(positions, dtype=np.float64), option=NUMPY)
    # "[[a,b],[c,d]]" → "[a,b]", "[c,d]": the rows' texts hold no "]" but their last, no NUL
    rows = text[1:-1].replace(b"],[", b"]\0[").split(b"\0")
    for i in np.flatnonzero(~np.asarray(observable, dtype=bool)).tolist():
        rows[i] = b"null"
    return rows


class EstimateParts:
    """Each agent's :class:`~formation.messages.AgentEstimate` (its in-neighbours' ``x̂`` and
    ``v_ref``) as JSON: alone (realtime, each on its agent's key) or all of them inside the
    estimates' :class:`~formation.messages.Bundle` (lockstep), each already escaped there.

    Both are joined from one table of pieces laid out once: an epoch's position rows, the
    pieces fixed for the run (each agent's opening, plain and escaped) and the epoch's
    own (its header and tail, plain and escaped; the bundle's header). A part's bytes inside the bundle
    are its bytes alone, escaped: a row needs no escaping (numbers, ``null``).

    in_neighbours : per agent ``i`` (row ``i − 1``) the ids of its in-neighbours
    header_format : :meth:`shell.Service.header_format` of the sender
    """

    def __init__(self, in_neighbours: Sequence[Sequence[int]], header_format: bytes) -> None:
        n = len(in_neighbours)
        self.header_format = header_format
        opens = [
            b',"kind":"agent_estimate","agent":%d,"neighbours":%b,"positions":['
            % (i, orjson.dumps(list(js)))
            for i, js in enumerate(in_neighbours, start=1)
        ]
        starts = [b'%b{"agent":%d,"seq":' % (b"," if i > 1 else b"", i) for i in range(1, n + 1)]
        # the table: rows [0, n), the fixed pieces, then the epoch's own (:meth:`_table`)
        fixed = [b",", *opens, *map(_escaped, opens), *starts, b"]}"]
        comma, end = n, n + len(fixed) - 1
        plain_open, escaped_open, start = n + 1, n + 1 + n, n + 1 + 2 * n
        head, tail, escaped_head, escaped_tail, bundle_head = range(
            n + len(fixed), n + len(fixed) + 5
        )
        self.fixed = fixed

        def positions(js: Sequence[int]) -> list[int]:
            return list(chain.from_iterable((comma, j - 1) for j in js))[1:]

        self.alone = [
            itemgetter(head, plain_open + i, *positions(js), tail)
            for i, js in enumerate(in_neighbours)
        ]
        whole = [bundle_head]
        for i, js in enumerate(in_neighbours):
            whole += [start + i, escaped_head, escaped_open + i, *positions(js), escaped_tail]
        self.whole = itemgetter(*whole, end)

    def _table(
        self, rows: list[bytes], v_ref: Sequence[float], epoch: int, stamp_ns: int, seq: int
    ) -> list[bytes]:
        head = self.header_format % (seq, epoch, stamp_ns)
        tail = b'],"v_ref":' + orjson.dumps(list(v_ref)) + b"}"
        opening = b'%d,"message":"' % seq + _escaped(head)
        return [*rows, *self.fixed, head, tail, opening, _escaped(tail) + b'"}']

    def texts(
        self, rows: list[bytes], v_ref: Sequence[float], epoch: int, stamp_ns: int, seq: int
    ) -> list[bytes]:
        """Every agent's part of epoch ``epoch`` alone: ``rows`` from :func:`position_rows`,
        ``seq`` the seq of every agent's key (they move together)."""
        table = self._table(rows, v_ref, epoch, stamp_ns, seq)
        return [b"".join(part(table)) for part in self.alone]

    def bundle(
        self,
        head: dict[str, object],
        rows: list[bytes],
        v_ref: Sequence[float],
        epoch: int,
        stamp_ns: int,
        seq: int,
    ) -> bytes:
        """The :class:`~formation.messages.Bundle` of every agent's part (as :meth:`texts`),
        ``head`` the bundle's own header."""
        table = self._table(rows, v_ref, epoch, stamp_ns, seq)
        table.append(
            orjson.dumps({**head, "kind": "bundle", "phase": "estimate", "parts": []})[:-2]
        )
        return b"".join(self.whole(table))


def _escaped(text: bytes) -> bytes:
    """``text`` as it reads inside a JSON string (escaping is character by character, so
    escaped pieces join into the escaped whole)."""
    return orjson.dumps(text.decode())[1:-1]


def estimate_message(
    head: dict[str, object],
    lead: LeaderEpoch,
    x_ref: list[float],
    v_ref: list[float],
    edges: npt.NDArray[np.int64],
    reports: int,
    rows: list[bytes] | None = None,
) -> bytes:
    """The whole :class:`~formation.messages.LeaderEstimate` as JSON, built with orjson
    (a test checks the model validates every field). ``rows``: :func:`position_rows` of
    ``lead``, when the caller has them.

    An epoch computed without covariances (``estimator.covariance_every``) has ``None`` for
    every agent's block."""
    res = lead.estimate
    rows = position_rows(res.positions, res.observable) if rows is None else rows
    return orjson.dumps(
        {
            **head,
            "kind": "estimate",
            "positions": orjson.Fragment(b"[" + b",".join(rows) + b"]"),
            "covariances": _blocks(res.covariances, res.observable),
            "observable": orjson.Fragment(orjson.dumps(res.observable, option=NUMPY)),
            "tree": orjson.Fragment(orjson.dumps(edges[lead.tree], option=NUMPY)),
            "healthy": orjson.Fragment(orjson.dumps(edges[lead.healthy], option=NUMPY)),
            "components": int(lead.components),
            "rigidity_rank": int(lead.rigidity_rank),
            "rigid": bool(lead.rigid),
            "x_ref": x_ref,
            "v_ref": v_ref,
            "reports_received": reports,
        }
    )


def _blocks(covariances: npt.NDArray[np.float64] | None, observable: npt.NDArray[np.bool_]) -> Any:
    """The covariance blocks as JSON: ``None`` for an unobservable agent's (or every one's)."""
    if covariances is None:
        return [None] * observable.size
    if observable.all():
        return orjson.Fragment(orjson.dumps(np.ascontiguousarray(covariances), option=NUMPY))
    return [
        c if ok else None for c, ok in zip(covariances.tolist(), observable.tolist(), strict=True)
    ]
