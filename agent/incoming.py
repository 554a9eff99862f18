"""What a phase delivered to a set of agents, as the arrays :class:`~agent.runner.AgentRunner`
steps with: the states' packets, and each agent's part of the leader's estimate.

A pool of hundreds takes hundreds of packets a phase; each distinct packet is read once
(the inbox's :class:`~shell.inbox.Columns`), and the rest is numpy.
"""

from __future__ import annotations

from itertools import chain
from operator import attrgetter
from typing import Any

import numpy as np
import numpy.typing as npt

from agent.runner import AgentRunner
from shell import Columns

Array = npt.NDArray[np.float64]
Ids = npt.NDArray[np.int64]
Mask = npt.NDArray[np.bool_]


def delivered_states(columns: Columns, dimension: int) -> tuple[Ids, Ids, Ids, Array]:
    """Each (receiver, packet) pair of a state phase: receivers, sources, sent epochs (m,)
    and the packets' positions ``x_j`` (m, d) [m]."""
    payloads = columns.payloads
    used = np.zeros(len(payloads), dtype=bool)
    used[columns.entry] = True
    table = np.zeros((len(payloads), dimension))
    if used.all():  # the usual: every packet is some pair's
        if payloads:
            table[:] = np.array(list(map(_POSITION, payloads)), dtype=float)
    elif used.any():
        rows = np.flatnonzero(used)
        table[rows] = np.array([payloads[e].position for e in rows.tolist()], dtype=float)
    entry = columns.entry
    return columns.receiver, columns.source[entry], columns.sent_epoch[entry], table[entry]


def delivered_estimates(columns: Columns, runner: AgentRunner) -> tuple[Array, Mask, Array, Mask]:
    """Each agent's first estimate of the phase, as :meth:`AgentRunner.step` takes it:
    ``v_ref`` (a, d) [m/s] and where it came (a,), each in-link's ``x̂_j`` (L, d) [m] and
    where it is known (L,). An estimate naming a neighbour twice counts the last."""
    a, d, n_links = len(runner.ids), runner.scenario.dimension, len(runner.links.index)
    v_ref, has_v_ref = np.zeros((a, d)), np.zeros(a, dtype=bool)
    estimate, has_estimate = np.zeros((n_links, d)), np.zeros(n_links, dtype=bool)
    receivers, first = np.unique(columns.receiver, return_index=True)
    if not receivers.size:
        return v_ref, has_v_ref, estimate, has_estimate
    messages = [columns.payloads[e] for e in columns.entry[first].tolist()]
    rows = runner.rows(receivers)
    v_ref[rows] = np.array([m.v_ref for m in messages], dtype=float)
    has_v_ref[rows] = True
    neighbours, positions = list(map(_NEIGHBOURS, messages)), list(map(_POSITIONS, messages))
    counts = list(map(len, neighbours))
    if counts != list(map(len, positions)):  # pairs as far as both lists go
        counts = list(map(min, counts, map(len, positions)))
        neighbours = [n[:c] for n, c in zip(neighbours, counts, strict=True)]
        positions = [p[:c] for p, c in zip(positions, counts, strict=True)]
    neighbour = list(chain.from_iterable(neighbours))
    position = list(chain.from_iterable(positions))
    link = runner.link_rows(np.repeat(receivers, counts), _ids(neighbour))
    last = _last_of_each(link)  # as a dict of the message's pairs holds them
    if last.size == len(position) and _each_of_length(position, d):  # the usual: all at once
        flat = np.fromiter(chain.from_iterable(position), dtype=float, count=len(position) * d)
        estimate[link] = flat.reshape(-1, d)
        has_estimate[link] = True
        return v_ref, has_v_ref, estimate, has_estimate
    known = [i for i in last.tolist() if position[i] is not None]
    if known:
        values = [position[i] for i in known]
        if {len(v) for v in values} != {d}:
            raise ValueError(f"an estimate's position is not of dimension {d}")
        flat = np.fromiter(chain.from_iterable(values), dtype=float, count=len(values) * d)
        estimate[link[known]] = flat.reshape(-1, d)
        has_estimate[link[known]] = True
    return v_ref, has_v_ref, estimate, has_estimate


_NEIGHBOURS, _POSITIONS = attrgetter("neighbours"), attrgetter("positions")
_POSITION = attrgetter("position")


def _each_of_length(values: list[Any], d: int) -> bool:
    """Whether every value is a list of ``d`` numbers (None, an unknown estimate, is not)."""
    try:
        return set(map(len, values)) <= {d}
    except TypeError:  # a None
        return False


def _ids(values: list[int]) -> Ids:
    """Agent ids as an array; one past int64 (a forged message) names no agent: −1."""
    try:
        return np.array(values, dtype=np.int64)
    except OverflowError:
        return np.array([v if -1 <= v < 2**62 else -1 for v in values], dtype=np.int64)


def _last_of_each(link: Ids) -> Ids:
    """The positions of ``link`` (≥ 0 only) that hold the last occurrence of their value."""
    ours = np.flatnonzero(link >= 0)
    if ours.size < 2 or np.bincount(link[ours]).max() < 2:  # no value twice: all of them
        return ours
    _, last = np.unique(link[ours][::-1], return_index=True)
    return np.sort(ours[ours.size - 1 - last])
