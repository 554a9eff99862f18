"""The leader's messages: token reports in as arrays, the estimate and each agent's part out as JSON.

A leader of a thousand agents reads a thousand reports and writes a thousand parts an
epoch: reports become columns at once, and the parts are JSON text from a template per
agent made once, each position's text written once for all the agents that receive it.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
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


class LinkIndex:
    """``(sender, receiver)`` → row of the scenario's directed links, for columns of pairs.

    links : (L, 2) ``(sender, receiver)`` agent ids, each pair once
    """

    def __init__(self, links: npt.NDArray[np.int64], n: int) -> None:
        self.base = n + 1  # ids are 1..n; anything else is no link
        pair = links[:, 0] * self.base + links[:, 1]
        self.order = np.argsort(pair, kind="stable")
        self.sorted = pair[self.order]

    def rows(self, senders: npt.ArrayLike, receivers: npt.ArrayLike) -> npt.NDArray[np.int64]:
        """The row of each pair, −1 where it is no link."""
        s, r = np.asarray(senders, dtype=np.int64), np.asarray(receivers, dtype=np.int64)
        inside = (s >= 0) & (s < self.base) & (r >= 0) & (r < self.base)
        pair = np.where(inside, s * self.base + r, -1)
        at = np.minimum(np.searchsorted(self.sorted, pair), max(self.sorted.size - 1, 0))
        found = inside & (self.sorted[at] == pair) if self.sorted.size else inside & False
        return np.where(found, self.order[at], -1)


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
    for report in reports:
        agent = report.agent
        for m in report.measurements:
            if m.token == 1 and m.z is not None and len(m.z) == d:
                senders.append(m.neighbour)
                receivers.append(agent)
                values.extend(m.z)
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
) -> list[str]:
    """Each agent's estimate as JSON text (``null`` when unobservable), written once an epoch."""
    return [
        _text(p) if ok else "null"
        for p, ok in zip(positions.tolist(), observable.tolist(), strict=True)
    ]


class EstimateParts:
    """Each agent's :class:`~formation.messages.AgentEstimate` (its in-neighbours' ``x̂`` and
    ``v_ref``) as JSON text, from a template per agent made once.

    in_neighbours : per agent ``i`` (row ``i − 1``) the ids of its in-neighbours
    header_format : :meth:`shell.Service.header_format` of the sender
    """

    def __init__(self, in_neighbours: Sequence[Sequence[int]], header_format: bytes) -> None:
        head = header_format.decode()
        self.templates = [
            f'{head},"kind":"agent_estimate","agent":{i},"neighbours":{_text(list(js))},"positions":['
            for i, js in enumerate(in_neighbours, start=1)
        ]
        self.rows = [[j - 1 for j in js] for js in in_neighbours]

    def texts(
        self, rows: list[str], v_ref: Sequence[float], epoch: int, stamp_ns: int, seqs: list[int]
    ) -> list[str]:
        """Every agent's part of epoch ``epoch``: ``rows`` from :func:`position_rows`, ``seqs``
        the seq of each agent's key."""
        tail = '],"v_ref":' + _text(list(v_ref)) + "}"
        return [
            template % (seq, epoch, stamp_ns) + ",".join([rows[j] for j in mine]) + tail
            for template, mine, seq in zip(self.templates, self.rows, seqs, strict=True)
        ]


def estimate_message(
    head: dict[str, object],
    lead: LeaderEpoch,
    x_ref: list[float],
    v_ref: list[float],
    edges: npt.NDArray[np.int64],
    reports: int,
    rows: list[str] | None = None,
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
            "positions": orjson.Fragment("[" + ",".join(rows) + "]"),
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


def _text(value: Any) -> str:
    return orjson.dumps(value).decode()


def _blocks(covariances: npt.NDArray[np.float64] | None, observable: npt.NDArray[np.bool_]) -> Any:
    """The covariance blocks as JSON: ``None`` for an unobservable agent's (or every one's)."""
    if covariances is None:
        return [None] * observable.size
    if observable.all():
        return orjson.Fragment(orjson.dumps(np.ascontiguousarray(covariances), option=NUMPY))
    return [
        c if ok else None for c, ok in zip(covariances.tolist(), observable.tolist(), strict=True)
    ]
