"""Lockstep packets on capacity queues: held until their phase's are all in, then judged together.

A queue serves a phase's packets in the order of their links, at the phase's start in
virtual time (docs/model.md §9), so none can be judged before every packet of its phase is
in, and phases must be judged in virtual-time order: states, reports, estimates, the next
epoch's states. :class:`QueuedPhases` holds what the models passed onto a queue and turns
each complete phase into decisions; :class:`netem.proxy.lockstep.LockstepCore` decides when a
phase is complete (its receivers' open epochs) and applies them.

A packet of a link alone in each of its queues (a ``link`` queue, or a radio or medium of
one link) meets no other packet there: it is judged at once (:meth:`QueuedPhases.at_once`).
A packet on the shared air (``netem.links.air_network``) always waits for its phase: what its
queues passed takes the air with the phase's others, at the positions of its epoch. With the
reports in the states' contention period (``network.air.reports = "with_states"``) the
states' phase is judged with the reports that will take the air then, since the reports are
sent only once the states are in: every agent's whose report link's model passes it (an
agent reports each epoch it takes part; queues and events are refused with this option).
The reports still wait for their phase, then take the fates decided with the states.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from formation.keys import LEADER_ENDPOINT
from formation.wire_size import Kind, WireSizes
from netem.links.air_network import AIR, AirNetwork, AirVerdict
from netem.links.capacity_network import PHASE_ORDER, CapacityNetwork, Fixed, packet_kind
from netem.links.layer_stack import Outcome
from netem.proxy.positions import Positions
from netem.proxy.records import Queued, queued
from netem.proxy.routes import Link, Links, Phase

PHASES: tuple[Phase, ...] = ("state", "report", "estimate")  # in virtual time
BLOCK = 1024  # epochs judged at once in closed form (:meth:`QueuedPhases.at_once`)
Held = tuple[Link, int, Any, Outcome]  # (link, seq, payload, the model's decision)


# a link's block of epochs judged in closed form: (from epoch, to epoch, the closed form or
# None, a decision of the model, each epoch's decision on a packet it passed)
_Block = tuple[int, int, Fixed | None, Outcome | None, list[Queued]]
_NONE: _Block = (0, 0, None, None, [])


class QueuedPhases:
    """The packets held for a run's queues, by (phase, epoch)."""

    def __init__(
        self,
        queues: CapacityNetwork,
        sizes: WireSizes,
        agents: list[int],
        air: tuple[AirNetwork, Positions] | None = None,
        reports: Callable[[int, int], bool] | None = None,
    ) -> None:
        self.queues, self.sizes, self.agents = queues, sizes, agents
        self.air = air  # the shared air and where its positions are read
        self.air_phases: frozenset[str] = frozenset() if air is None else air[0].phases
        # with the reports in the states' period: whether agent i's report of epoch k takes
        # the air (its link's model passes it), and the reports' fates until their phase
        self.reports = reports if air is not None and air[0].reports_with_states else None
        self.report_fates: dict[int, dict[int, AirVerdict]] = {}
        self.held: dict[tuple[Phase, int], list[Held]] = {}
        self._links: dict[Link, tuple[tuple[int, int], Kind, int]] = {}  # (src, dst), kind, whose
        self._fixed: dict[Link, _Block] = {}  # each link's block of closed-form verdicts

    def __bool__(self) -> bool:
        return bool(self.held)

    def __contains__(self, key: tuple[Phase, int]) -> bool:
        return key in self.held

    def at_once(self, phase: Phase, epoch: int, link: Link, d: Outcome) -> Outcome | Queued | None:
        """The decision on a packet the model passed (``d``) as far as it can be taken now:
        ``d`` when no queue serves its link at ``epoch``; the queues' when its link is alone in
        each of its own (:meth:`CapacityNetwork.alone`, or its closed form for a block of
        epochs, :meth:`CapacityNetwork.fixed`); None when it waits for the rest of its phase
        (:meth:`hold`)."""
        if phase in self.air_phases:
            return None  # it takes the air with its phase's others
        net = self.queues
        start, end, block, usual, decided = self._fixed.get(link, _NONE)
        if not start <= epoch < end:  # a new block (or none yet): is the link alone in its queues?
            pair, _, _ = self._route(link)
            if epoch < net.first_epoch.get(pair, math.inf):
                return d
            if pair not in net.solo:
                return None
            start, end, block, usual, decided = self._fix(phase, epoch, link, d)
        if block is not None and block.link in net.idle:
            j = epoch - start
            last = net.last_in.get(block.link)
            if last is None or last[2] <= block.t0_s[j]:  # its queues are idle: closed form
                t0, payload, t = block.t0_s[j], block.payload_bytes[j], block.departure_s[j]
                net.last_in[block.link] = (t0, payload, t)
                if d is usual:
                    return decided[j]
                return queued(d, block.reason[j], block.queue, 0, block.sojourn_ms[j])
        pair, kind, whose = self._route(link)
        v = net.alone(epoch, phase, pair, self.sizes.payload_bytes(kind, whose, epoch))
        return queued(d, *v)

    def _route(self, link: Link) -> tuple[tuple[int, int], Kind, int]:
        """``link``'s ends, and the kind and whose its packets are."""
        got = self._links.get(link)
        if got is None:
            pair = (link[1], link[2])
            got = self._links[link] = (pair, *packet_kind(pair))
        return got

    def _fix(self, phase: Phase, epoch: int, link: Link, d: Outcome) -> _Block:
        """The closed form of ``link``'s :data:`BLOCK` epochs from ``epoch`` (None: it has none,
        :meth:`CapacityNetwork.fixed`), with each epoch's decision on a packet the model's ``d``
        passed (the model's decisions are shared: most of its packets have that one)."""
        pair, kind, whose = self._route(link)
        epochs = np.arange(epoch, epoch + BLOCK, dtype=np.int64)
        payloads = self.sizes.payload_bytes_of(kind, whose, epochs)
        block = self.queues.fixed(pair, phase, epochs, payloads)
        decided: list[Queued] = []
        if block is not None:  # few distinct (reason, sojourn): one decision each
            pairs = list(zip(block.reason, block.sojourn_ms, strict=True))
            each = {p: queued(d, p[0], block.queue, 0, p[1]) for p in set(pairs)}
            decided = [each[p] for p in pairs]
        got = self._fixed[link] = (epoch, epoch + BLOCK, block, d, decided)
        return got

    def hold(self, phase: Phase, epoch: int, held: Held) -> None:
        self.held.setdefault((phase, epoch), []).append(held)

    def receivers(self, phase: Phase) -> list[int]:
        return [LEADER_ENDPOINT] if phase == "report" else self.agents

    def earlier(self, phase: Phase, epoch: int) -> list[tuple[Phase, int]]:
        """The phases just before ``epoch`` of ``phase`` in virtual time whose packets cross a
        queue (the others cannot come out of turn)."""
        before: list[tuple[Phase, int]] = [(p, epoch) for p in PHASES[: PHASE_ORDER[phase]]]
        if epoch > 0:
            before.append(("estimate", epoch - 1))
        return [(p, e) for p, e in before if p in self.queues.phases or p in self.air_phases]

    def judge(self, phase: Phase, epoch: int) -> list[tuple[Link, int, Any, Queued]]:
        """The held packets of ``epoch`` of ``phase`` through their queues, their decisions."""
        held = self.held.pop((phase, epoch))
        packets = [
            ((src, dst), self.sizes.payload_bytes(*packet_kind((src, dst)), epoch))
            for (_, src, dst), _, _, _ in held
        ]
        verdicts = self.queues.phase(epoch, phase, packets)
        out = [
            (link, seq, payload, queued(d, v.reason, v.queue, v.depth, v.sojourn_ms))
            for (link, seq, payload, d), v in zip(held, verdicts, strict=True)
        ]
        if self.air is None or phase not in self.air_phases:
            return out
        net, positions = self.air
        on_air = [p for p, v in enumerate(verdicts) if v.passed]
        pairs = [packets[p][0] for p in on_air]
        if self.reports is not None and phase == "state":
            fates = self._with_states(epoch, pairs)
        elif self.reports is not None and phase == "report":  # decided with their states
            if epoch not in self.report_fates:  # none of which took the air
                self._with_states(epoch, [])
            decided = self.report_fates.pop(epoch)
            fates = [decided[src] for src, _ in pairs]
        else:
            fates = net.phase(epoch, phase, pairs, positions.of_epoch(epoch))
        for p, fate in zip(on_air, fates, strict=True):
            link, seq, payload, d = held[p]
            arrival = fate.arrival_ms if fate.passed else math.nan
            out[p] = (link, seq, payload, queued(d, fate.cause, AIR, fate.frames, arrival))
        return out

    def _with_states(self, epoch: int, states: list[tuple[int, int]]) -> list[AirVerdict]:
        """The fates of the states' period of ``epoch``: the states' (returned) and the reports'
        that will take the air then (kept for their phase)."""
        assert self.air is not None and self.reports is not None  # only with the reports so
        net, positions = self.air
        reporters = [a for a in self.agents if self.reports(a, epoch)]
        reports = [(a, LEADER_ENDPOINT) for a in reporters]
        fates, later = net.with_states(epoch, states, reports, positions.of_epoch(epoch))
        self.report_fates[epoch] = dict(zip(reporters, later, strict=True))
        self.report_fates.pop(epoch - 2, None)  # none of them passed its link (kept nothing)
        return fates

    def waiting(self) -> list[tuple[Phase, int]]:
        """The phases still held, in virtual-time order."""
        return sorted(self.held, key=lambda pe: (pe[1], PHASE_ORDER[pe[0]]))


def queued_phases(links: Links, positions: Positions) -> QueuedPhases | None:
    """The phases ``links``' packets wait in: for capacity queues, the shared air, or both
    (None: neither)."""
    if links.air is None:
        if links.capacity is None or links.sizes is None:
            return None
        return QueuedPhases(links.capacity, links.sizes, links.agents)
    # no queue: an empty network keeps the phases in order
    queues = links.capacity or CapacityNetwork([], len(links.agents), [], links.air.period_s)
    sizes = links.sizes or links.air.sizes

    def reports(agent: int, epoch: int) -> bool:
        """Whether the model of ``agent``'s report link passes its report of ``epoch``."""
        link: Link = ("report", agent, LEADER_ENDPOINT)
        model = links.models[link]
        return model.decide(epoch, distance_m=positions.length(link, epoch)).delivered

    return QueuedPhases(queues, sizes, links.agents, (links.air, positions), reports)


__all__ = ["PHASES", "Held", "QueuedPhases", "queued_phases"]
