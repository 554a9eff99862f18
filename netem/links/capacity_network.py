"""A scenario's capacity queues over a run's phases, in virtual time (docs/model.md §9).

Each epoch ``k`` has three phases (``formation.deadlines.PHASES``): states from ``k T``,
reports from ``(k + 0.20) T``, estimates from ``(k + 0.60) T``, each due by its deadline
(``0.20``, ``0.60``, ``0.85`` of the period ``T``), as the realtime mode's. Every packet of
a phase that its link's loss models passed arrives at its queues at the phase's start, in
the order of its link ``(src, dst)``; it goes through its link's queue, then its sender's
radio, then its medium (``formation.capacity.queues_of``), each a
:func:`netem.links.capacity.serve_queue` carrying its state from phase to phase. A packet one of
them refuses is ``queue_full`` (or ``oversize``); one leaving the last after the phase's
deadline is ``queue_late``.

netem's lockstep and the simulator call :meth:`CapacityNetwork.phase` with the same packets
(sizes from ``formation.wire_size``) in the same (epoch, phase) order, so they drop the
same ones, bit for bit; netem judges a packet of a link alone in its queues as it comes
(:meth:`CapacityNetwork.alone`), which no other packet of its phase could change.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from formation.capacity import Capacity, Link, all_links, members, queues_of
from formation.deadlines import PHASES
from formation.errors import LinkModelError
from formation.keys import LEADER_ENDPOINT
from formation.scenario import Scenario
from formation.wire_size import Kind
from netem.links.capacity import (
    PASSED,
    QUEUE_LATE,
    REASONS,
    QueueParams,
    QueueState,
    make_room,
    serve_packets,
)
from netem.links.capacity_held import HeldQueues

PHASE_ORDER = {"state": 0, "report": 1, "estimate": 2}


class QueueVerdict(NamedTuple):
    """One packet's fate in the queues: ``reason`` (``""``: passed in time), the queue that
    decided, its depth then [packets] and the packet's time in the queues [ms]."""

    reason: str
    queue: str
    depth: int
    sojourn_ms: float

    @property
    def passed(self) -> bool:
        return not self.reason


def params_of(c: Capacity) -> QueueParams:
    """The core's parameters of a scenario's capacity entry."""
    return QueueParams(
        rate_bps=c.rate_bps,
        burst_bytes=c.burst_bytes,
        limit_packets=c.limit_packets,
        limit_bytes=c.limit_bytes,
        overhead_bytes=c.overhead_bytes,
        policy=c.policy,
    )


class Fixed(NamedTuple):
    """:meth:`CapacityNetwork.fixed`: ``link``'s packets of epochs ``start`` to ``end`` (excluded),
    by epoch: their reasons, their last queue, sojourns [ms], phase starts [s], payloads [B]
    and departures [s]."""

    link: Link
    start: int
    end: int
    reason: list[str]
    queue: str
    sojourn_ms: list[float]
    t0_s: list[float]
    payload_bytes: list[int]
    departure_s: list[float]


class CapacityNetwork:
    """The queues of one run (one seed): their parameters, which links they serve, their state."""

    def __init__(
        self,
        capacities: Sequence[Capacity],
        n: int,
        formation_links: Sequence[Sequence[int]],
        period_s: float,
    ) -> None:
        self.capacities = list(capacities)
        self.params = [params_of(c) for c in capacities]
        self.names = [c.name for c in capacities]
        self.links = all_links(n, formation_links)
        self.period_s = period_s
        self.states: list[QueueState | None] = [None] * len(capacities)
        self.since = [0] * len(capacities)  # the epoch from which each queue serves
        self._changes: list[tuple[int, int, QueueParams]] = []  # (from epoch, queue, params)
        self._last = (-1, -1)  # (epoch, phase) of the last call
        self.held = HeldQueues(self.params)  # realtime: the packets each queue holds
        self._route()
        # Links :meth:`alone` judges in closed form: the stages (queue, rate [B/s], overhead
        # [B], limit [B]) of links alone in queues of ``burst_bytes = 0``, none changed yet.
        self.idle: dict[Link, tuple[tuple[int, float, int, int | None], ...]] = {}
        for lk, ks in self.by_link.items():
            ps = [self.params[k] for k in ks]
            if lk in self.solo and not any(p.burst_bytes for p in ps):
                self.idle[lk] = tuple(
                    (k, p.rate_bps / 8.0, p.overhead_bytes, p.limit_bytes)
                    for k, p in zip(ks, ps, strict=True)
                )
        # its last packet: (its phase's start [s], payload [B], when it left the last queue [s])
        self.last_in: dict[Link, tuple[float, int, float]] = {}

    def _route(self) -> None:
        """Which queues serve each link; which links are alone in all of theirs (:meth:`alone`);
        the phases whose packets wait for their phase (those of the others)."""
        self.by_link = queues_of(self.capacities, self.links)
        served: dict[int, int] = {}
        for ks in self.by_link.values():
            for k in ks:
                served[k] = served.get(k, 0) + 1
        self.solo = frozenset(
            lk for lk, ks in self.by_link.items() if all(served[k] == 1 for k in ks)
        )
        self.phases = _phases([lk for lk in self.by_link if lk not in self.solo])
        # the epoch from which a queue serves each link
        self.first_epoch = {lk: min(self.since[k] for k in ks) for lk, ks in self.by_link.items()}

    def constrained(self, link: Link, epoch: int = 0) -> bool:
        """Does a queue serve ``link`` at ``epoch``?"""
        return epoch >= self.first_epoch.get(link, math.inf)

    def change(self, capacity: Capacity, from_epoch: int) -> list[Link]:
        """``capacity``'s queue (the one of its scope and target, or a new link queue) takes its
        parameters from ``from_epoch`` on (all of them, as ``tc qdisc change``: an unnamed one
        takes its default), its links and state kept; returns the links it serves.

        A radio or medium the scenario has no queue for is refused (``ValueError``): those
        name sets of links the scenario defines.
        """
        k = next((q for q, c in enumerate(self.capacities) if c.name == capacity.name), None)
        if k is None:
            if capacity.scope != "link":
                raise ValueError(
                    f"{capacity.name}: no such queue in the scenario's network.capacity"
                )
            served = members(capacity, self.links)
            if not served or served[0] not in self.links["all"]:
                raise ValueError(f"{capacity.name}: no such link in the scenario")
            k = len(self.capacities)
            self.capacities.append(capacity)
            self.params.append(params_of(capacity))
            self.names.append(capacity.name)
            self.states.append(None)
            self.since.append(from_epoch)
            self._route()
            for lk in served:
                self._not_idle(lk)
        else:  # the queue keeps its links; its parameters are all replaced, as tc's
            tc = (
                "rate_bps",
                "burst_bytes",
                "limit_packets",
                "limit_bytes",
                "overhead_bytes",
                "policy",
            )
            capacity = self.capacities[k].model_copy(update={f: getattr(capacity, f) for f in tc})
            self._changes.append((from_epoch, k, params_of(capacity)))
            for lk in members(capacity, self.links):
                self._not_idle(lk)
            self.capacities[k] = capacity
        return members(capacity, self.links)

    def _params(self, k: int, epoch: int) -> QueueParams:
        """Queue ``k``'s parameters at ``epoch``, its changes due by then applied (:meth:`change`);
        a queue is served in epoch order, so each takes its own as it comes to them."""
        if self._changes:
            for change in [c for c in self._changes if c[1] == k and c[0] <= epoch]:
                self.params[k] = change[2]
                self._changes.remove(change)
        return self.params[k]

    def arrive(
        self,
        link: Link,
        payload_bytes: int,
        now_s: float,
        epoch: int,
        deadline_s: float,
        token: int = 0,
    ) -> tuple[QueueVerdict, float, list[int]]:
        """Realtime: one packet of ``epoch`` at ``now_s`` [s since the clock's start] through its
        queues, decided at once; its verdict, when it leaves the last [s] (NaN: dropped), and
        the tokens of the packets it pushed out of ``oldest`` queues (:func:`make_room`).

        Packets come one at a time as they arrive, so each queue is FIFO in the order netem
        handles them. ``token`` names the packet in its queues until it leaves them; a packet
        pushed out leaves every queue it was in.
        """
        return self._through(link, payload_bytes, now_s, epoch, deadline_s, token)

    def alone(self, epoch: int, phase: str, link: Link, payload_bytes: int) -> QueueVerdict:
        """Lockstep: the fate of a packet of a link in :attr:`solo`, judged at once.

        Each of its queues serves that link alone, so no other packet of its phase comes
        before it in any of them: this is :meth:`phase`'s verdict on it, without waiting for
        the phase. Calls for one link come in epoch order, as its sender sends.

        Queues of ``burst_bytes = 0`` that the link's previous packet has left, and that hold
        its size, serve it at once (docs/model.md §9): it leaves each ``8 s / r`` after it
        came, in closed form, their states kept as that packet's departure until needed.
        """
        start, deadline = PHASES[phase]
        t0 = (epoch + start) * self.period_s  # [s]
        due = (epoch + deadline) * self.period_s
        stages = self.idle.get(link)
        if stages is not None:
            last = self.last_in.get(link)
            t = t0 if last is None or last[2] <= t0 else math.nan
            for _, rate, extra, limit in stages:
                size = payload_bytes + extra
                t = math.nan if limit is not None and size > limit else t + size / rate
            if t == t:  # not NaN: every queue was idle and held it
                self.last_in[link] = (t0, payload_bytes, t)
                name = self.names[stages[-1][0]]
                return QueueVerdict(_LATE if t > due else "", name, 0, 1e3 * (t - t0))
            self._not_idle(link)
        return self._through(link, payload_bytes, t0, epoch, due)[0]

    def fixed(
        self, link: Link, phase: str, epochs: npt.NDArray[np.int64], payloads: npt.NDArray[np.int64]
    ) -> Fixed | None:
        """:meth:`alone`'s closed form for a block of a link's packets at once (``epochs``
        increasing, one payload [B] each); None unless its queues serve each of them within
        half a period, so that each finds them idle whatever passed before.

        The same arithmetic as :meth:`alone`, on arrays; the caller notes each packet it
        judges by it in :attr:`last_in`, as :meth:`alone` does.
        """
        stages = self.idle.get(link)
        if stages is None:
            return None
        start, deadline = PHASES[phase]
        t0 = (epochs + start) * self.period_s  # [s]
        t = t0
        for _, rate, extra, limit in stages:
            size = payloads + extra
            if limit is not None and (size > limit).any():
                return None
            t = t + size / rate
        if ((t - t0) > 0.5 * self.period_s).any():
            return None
        late = t > (epochs + deadline) * self.period_s
        return Fixed(
            link,
            int(epochs[0]),
            int(epochs[-1]) + 1,
            np.where(late, _LATE, "").tolist(),
            self.names[stages[-1][0]],
            (1e3 * (t - t0)).tolist(),
            t0.tolist(),
            payloads.tolist(),
            t.tolist(),
        )

    def _not_idle(self, link: Link) -> None:
        """``link`` is judged in full from now on: its queues take the states that the packets
        judged in closed form left (:meth:`alone`), as :func:`serve_packets` leaves them."""
        stages, last = self.idle.pop(link, None), self.last_in.pop(link, None)
        if stages is None or last is None:
            return
        t, payload, _ = last
        for k, rate, extra, _ in stages:
            size = payload + extra
            t = t + size / rate
            self.states[k] = QueueState(t, 0.0, (t,), (size,))  # a netem rate's bucket: 0

    def _through(
        self,
        link: Link,
        payload_bytes: int,
        t0: float,
        epoch: int,
        due: float,
        token: int | None = None,
    ) -> tuple[QueueVerdict, float, list[int]]:
        """One packet arriving at ``t0`` [s] through its link's queues in turn, each judging it
        alone; its verdict, when it leaves the last [s] (NaN: dropped), and the tokens of those
        it pushed out (realtime, with a ``token``: :meth:`arrive`)."""
        t, depth, name = t0, 0, ""
        pushed: list[int] = []
        passed: list[int] = []
        victims: list[int]
        for k in self.by_link.get(link, ()):
            if self.since[k] > epoch:
                continue
            params = self._params(k, epoch)
            size = payload_bytes + params.overhead_bytes
            state, victims = self.states[k], []
            if token is not None:
                self.held.settle(k, t0)  # now: a later queue's t is ahead of it
                state, victims = make_room(params, self.held.state(k), t, size)
                if victims:
                    gone = self.held.tokens(k, victims)
                    self.held.remove(gone, t)
                    pushed += gone
                    state = self.held.state(k)
            run = serve_packets(params, [t], [size], state=state)
            self.states[k] = run.state
            name, depth = self.names[k], run.depth[0] + len(victims)
            if run.reason[0] != PASSED:
                sojourn_ms = 1e3 * (t - t0 + run.sojourn_s[0])
                verdict = QueueVerdict(REASONS[run.reason[0]], name, depth, sojourn_ms)
                t = math.nan
                break
            if token is not None:
                self.held.add(k, token, t, size, run)
                passed.append(k)
            t = run.departure_s[0]
        else:
            verdict = QueueVerdict(_LATE if t > due else "", name, depth, 1e3 * (t - t0))
            if token is not None and passed:
                self.held.route[token] = tuple(passed)
        for q in self.held.held if pushed else ():  # as the packets pushed out left them
            self.states[q] = self.held.state(q)
        return verdict, t, pushed

    def retimed(self) -> dict[int, float]:
        """Realtime: the held packets whose departure from their last queue [s] changed since
        the last call, as packets pushed out ahead of them gave their link time back."""
        out, self.held.retimed = self.held.retimed, {}
        return out

    def phase(
        self, epoch: int, phase: str, packets: Sequence[tuple[Link, int]]
    ) -> list[QueueVerdict]:
        """The fates of one phase's packets ``(link, payload bytes)`` that the models passed.

        Calls come in (epoch, phase) order; packets of a link no queue serves pass.
        """
        at = (epoch, PHASE_ORDER[phase])
        if at <= self._last:
            raise LinkModelError(
                "capacity", f"{phase} of epoch {epoch} after {self._last}: phases go in order"
            )
        self._last = at
        start, deadline = PHASES[phase]
        t0 = (epoch + start) * self.period_s  # [s]
        due = (epoch + deadline) * self.period_s
        n = len(packets)
        by_link = self.by_link
        if any(self.since):  # a queue added while running serves from its epoch on
            by_link = {
                lk: tuple(k for k in ks if self.since[k] <= epoch) for lk, ks in by_link.items()
            }
        # (link, index, its queues) of the packets a queue serves, in link order
        alive = sorted(
            (link, i, qs) for i, (link, _) in enumerate(packets) if (qs := by_link.get(link))
        )
        time = [t0] * n
        out = [_NONE] * n
        last: dict[int, tuple[str, int]] = {}  # packet → (its last queue, its depth there)
        for stage in range(max((len(qs) for _, _, qs in alive), default=0)):
            groups: dict[int, list[int]] = {}
            for _, i, qs in alive:
                if stage < len(qs):
                    groups.setdefault(qs[stage], []).append(i)
            for q in sorted(groups):
                members = groups[q]
                if stage:  # in the order they reach it; stable: link order on ties
                    members.sort(key=time.__getitem__)
                params = self._params(q, epoch)
                extra = params.overhead_bytes
                run = serve_packets(
                    params,
                    [time[i] for i in members],
                    [packets[i][1] + extra for i in members],
                    state=self.states[q],
                )
                self.states[q] = run.state
                name = self.names[q]
                for m, i in enumerate(members):
                    if run.reason[m] == PASSED:
                        time[i] = run.departure_s[m]
                        last[i] = (name, run.depth[m])
                    else:
                        sojourn_ms = 1e3 * (time[i] - t0 + run.sojourn_s[m])
                        out[i] = QueueVerdict(
                            REASONS[run.reason[m]], name, run.depth[m], sojourn_ms
                        )
            alive = [p for p in alive if out[p[1]] is _NONE]  # dropped here: no further
        for _, i, _ in alive:
            name, depth = last[i]
            out[i] = QueueVerdict(_LATE if time[i] > due else "", name, depth, 1e3 * (time[i] - t0))
        return out


_NONE = QueueVerdict("", "", 0, 0.0)  # no queue serves the packet's link
_LATE = REASONS[QUEUE_LATE]


def _phases(links: Sequence[Link]) -> frozenset[str]:
    return frozenset(packet_kind(link)[0] for link in links)


def packet_kind(link: Link) -> tuple[Kind, int]:
    """Which packet a link carries, and whose: a state (its sender's), a report, an estimate."""
    src, dst = link
    if dst == LEADER_ENDPOINT:
        return "report", src
    if src == LEADER_ENDPOINT:
        return "estimate", dst
    return "state", src


def network_of(scenario: Scenario) -> CapacityNetwork:
    """The queues of ``scenario``'s ``network.capacity``, over its lockstep period."""
    return CapacityNetwork(
        scenario.network.capacity,
        scenario.n,
        scenario.directed_links.tolist(),
        scenario.control.period_s,
    )


__all__ = [
    "PHASE_ORDER",
    "CapacityNetwork",
    "Fixed",
    "QueueVerdict",
    "network_of",
    "packet_kind",
    "params_of",
]
