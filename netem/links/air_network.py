"""A scenario's shared air over a run's phases: each phase's packets as 802.11 frames.

``[network.air]`` (``formation.air``) puts a class of links on one channel. In each phase
of an epoch (``formation.deadlines.PHASES``: states, reports, estimates), the packets on the
air that the loss models and capacity queues passed become frames, decided together by
:func:`netem.links.wifi.decide_phase` from the agents' true positions of the epoch (the
leader's end of a control link at ``network.access_point``): a state is one broadcast from
its sender (or a unicast per link), a report or estimate a unicast. Each sender's frames are
ready at a keyed offset ``U[0, start_spread_us)`` from the phase's start; a frame received
after the phase's deadline is ``late``. With ``reports = "with_states"`` the reports take the
air in the states' period (:meth:`AirNetwork.with_states`), on the states' channel or on one of
their own; ``estimation_traffic = "when_used"`` keeps reports and estimates off the air in a
run whose strategy never reads the estimates. netem's lockstep and the simulator give
:meth:`AirNetwork.phase` the same packets, so both drop the same, bit for bit
(docs/model.md §11).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from formation.air import AIR_QUEUE, Air, air_problems
from formation.deadlines import PHASES
from formation.keyed_random import Stream, keyed_uniform
from formation.keys import LEADER_ENDPOINT
from formation.scenario import Scenario
from formation.wire_size import WireSizes
from netem.links.capacity_network import PHASE_ORDER, packet_kind
from netem.links.wifi import (
    BROADCAST,
    AirConfig,
    Cause,
    Frames,
    Key,
    PhaseOutcome,
    decide_phase,
)

Link = tuple[int, int]  # (src, dst); 0 is the leader's end
START = 2  # sub-stream of Stream.AIR: the senders' start offsets (0, 1: the model's)
FAR_M = 1e9  # [m] where an agent whose position is unknown is put: out of everyone's range
AIR = AIR_QUEUE  # the medium's name in decision records (their ``queue``)
CAUSES = tuple(c.name.lower() for c in Cause)  # "delivered", "collision", ...
_CLASS = {"state": "formation", "report": "report", "estimate": "estimate"}


class AirVerdict(NamedTuple):
    """One packet's fate on the air: ``cause`` (``""``: delivered in time), when it arrived
    [ms from its phase's start] (NaN: not delivered), its frame's transmissions, and how
    many frames took the air in its phase."""

    cause: str
    arrival_ms: float
    attempts: int
    frames: int

    @property
    def passed(self) -> bool:
        return not self.cause


class AirNetwork:
    """The channel of one run (one seed): its radio, the links on it, the phases' timing."""

    def __init__(self, scenario: Scenario, seed: int, strategy: str | None = None) -> None:
        """``strategy``: the run's (None: the scenario's), which decides whether the
        estimation traffic takes the air (``Air.estimation_traffic``)."""
        air = scenario.network.air
        if air is None:
            raise ValueError(f"{scenario.name}: no [network.air]")
        self.air: Air = air
        self.config = AirConfig(**air.radio())
        self.seed = seed
        self.n = scenario.n
        self.period_s = scenario.control.period_s
        ap = scenario.network.access_point
        self.access_point = None if ap is None else np.asarray(ap, dtype=np.float64)
        self.sizes = WireSizes(scenario)
        run = scenario.strategy.name if strategy is None else strategy
        self.phases = frozenset(p for p, c in _CLASS.items() if air.carries(c, run))
        # (from epoch, the air, its model's config): the scenario's, then each change's
        self.eras: list[tuple[int, Air, AirConfig]] = [(0, air, self.config)]

    @property
    def reports_with_states(self) -> bool:
        """Whether the reports take the air, in the states' contention period."""
        return self.air.reports_with_states and "report" in self.phases

    def change(self, update: dict[str, object], from_epoch: int) -> Air:
        """The air's parameters ``update`` from ``from_epoch`` on (``formation netem set
        medium:air``); the links on it stay. A ``ValueError`` names a field it refuses."""
        fixed = sorted(
            {"kind", "links", "reports", "control_channel", "estimation_traffic"} & set(update)
        )
        if fixed:
            raise ValueError(f"{fixed[0]}: which links take the air, and when, is the scenario's")
        now = self.eras[-1][1]
        air = Air.model_validate({**now.model_dump(exclude_none=True), **update})
        problems = air_problems(air, None if self.access_point is None else (0.0,))
        if problems:
            field, value, problem = problems[0]
            raise ValueError(f"{field.removeprefix('network.air.')} = {value!r}; {problem}")
        self.eras = [e for e in self.eras if e[0] < from_epoch]
        self.eras.append((from_epoch, air, AirConfig(**air.radio())))
        return air

    def at(self, epoch: int) -> tuple[Air, AirConfig]:
        """The air and its model's config in force at ``epoch``."""
        for start, air, config in reversed(self.eras):
            if start <= epoch:
                return air, config
        return self.air, self.config

    def carries(self, link: Link) -> bool:
        """Whether ``link``'s packets take the air."""
        return packet_kind(link)[0] in self.phases

    def payload_bytes(self, link: Link, epoch: int) -> int:
        fixed = self.at(epoch)[0].payload_bytes
        if fixed is not None:
            return fixed
        return self.sizes.payload_bytes(*packet_kind(link), epoch)

    def phase(
        self,
        epoch: int,
        phase: str,
        links: Sequence[Link],
        positions_m: npt.ArrayLike,
        ready_ns: Sequence[int] | None = None,
        end_ns: int | None = None,
    ) -> list[AirVerdict]:
        """The fates of one phase's packets on the air, one per link of ``links``.

        Parameters
        ----------
        links : the links whose packet of ``epoch`` the models and queues passed, each carried
        positions_m : (n, d) array [m]
            The agents' true positions at ``epoch`` (row ``i − 1``: agent ``i``); a row of NaN
            for an agent whose position is not known (one not taking part).
        ready_ns, end_ns : realtime's: when each packet came and its deadline [ns from the
            phase's origin]; None: the keyed start offsets and the phase's deadline
        """
        if not links:
            return []
        x = self._positions(positions_m)
        air, config = self.at(epoch)
        senders, receivers, sizes, which = self._frames(air, epoch, phase, links)
        if ready_ns is None:
            offsets = self._offsets(air, epoch, phase, senders)
        else:  # each frame when its packet came
            came = [0] * len(senders)
            for p in range(len(links)):
                came[which[p]] = ready_ns[p]
            offsets = np.asarray(came, dtype=np.int64)
        frames = Frames.of(senders, receivers, sizes, offsets)
        if end_ns is None:
            end_ns = self._deadline_ns(phase)
        out = decide_phase(config, x, frames, Key(self.seed, epoch, PHASE_ORDER[phase]), end_ns)
        return self._verdicts(out, links, which, 0, len(frames), end_ns)

    def with_states(
        self,
        epoch: int,
        states: Sequence[Link],
        reports: Sequence[Link],
        positions_m: npt.ArrayLike,
    ) -> tuple[list[AirVerdict], list[AirVerdict]]:
        """The fates of the states and the reports of ``epoch`` when the reports take the air in
        the states' contention period (``reports = "with_states"``; docs/model.md §11).

        Each agent's report is ready at its state's keyed start offset, queued behind its state;
        on the states' channel (``control_channel = "shared"``) both contend in one phase, on a
        channel of their own (``"own"``) the reports contend only with each other (the same
        radio and offsets, their own backoff draws). Each packet is late after its own
        deadline (``formation.deadlines.PHASES``: the states' 0.2, the reports' 0.6 of the
        period); arrivals are from the epoch's start.
        """
        x = self._positions(positions_m)
        air, config = self.at(epoch)
        if air.control_channel == "own":
            return (
                self.phase(epoch, "state", states, x[: self.n]) if states else [],
                self._period(air, config, x, epoch, [], reports, "report"),
            )
        verdicts = self._period(air, config, x, epoch, states, reports, "state")
        return verdicts[: len(states)], verdicts[len(states) :]

    def _period(
        self,
        air: Air,
        config: AirConfig,
        x: npt.NDArray[np.float64],
        epoch: int,
        states: Sequence[Link],
        reports: Sequence[Link],
        keyed_as: str,
    ) -> list[AirVerdict]:
        """The states' then the reports' fates in one contention period from the epoch's start
        (each sender's frames at its state's offset), the backoffs keyed by ``keyed_as``."""
        if not states and not reports:
            return []
        s_senders, s_receivers, s_sizes, s_which = self._frames(air, epoch, "state", states)
        r_senders, r_receivers, r_sizes, r_which = self._frames(air, epoch, "report", reports)
        senders = s_senders + r_senders
        offsets = self._offsets(air, epoch, "state", senders)
        frames = Frames.of(senders, s_receivers + r_receivers, s_sizes + r_sizes, offsets)
        out = decide_phase(config, x, frames, Key(self.seed, epoch, PHASE_ORDER[keyed_as]))
        m = len(frames)
        return [
            *self._verdicts(out, states, s_which, 0, m, self._deadline_ns("state")),
            *self._verdicts(out, reports, r_which, len(s_senders), m, self._deadline_ns("report")),
        ]

    def _positions(self, positions_m: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """The rows the model takes: the agents' (an unknown one far away), the leader's radio."""
        x = np.asarray(positions_m, dtype=np.float64)
        x = np.where(np.isnan(x), FAR_M * np.arange(1, x.shape[0] + 1)[:, None], x)
        if self.access_point is not None:
            x = np.vstack([x, self.access_point[None, :]])  # node n: the leader's radio
        return x

    def _frames(
        self, air: Air, epoch: int, phase: str, links: Sequence[Link]
    ) -> tuple[list[int], list[int], list[int], list[int]]:
        """The frames of ``links``' packets of ``phase``: their senders' and receivers' rows,
        their payloads [B], and each link's frame. A broadcast state is one frame per sender
        (in sender order); unicast frames go in link order."""
        node = [self._node(src) for src, _ in links]
        if phase == "state" and air.states == "broadcast":
            senders = sorted(set(node))
            frame_of = {s: f for f, s in enumerate(senders)}
            size = {node[p]: self.payload_bytes(lk, epoch) for p, lk in enumerate(links)}
            receivers = [BROADCAST] * len(senders)
            return senders, receivers, [size[s] for s in senders], [frame_of[s] for s in node]
        order = sorted(range(len(links)), key=lambda p: links[p])
        which = [0] * len(links)
        for f, p in enumerate(order):
            which[p] = f
        return (
            [node[p] for p in order],
            [self._node(links[p][1]) for p in order],
            [self.payload_bytes(links[p], epoch) for p in order],
            which,
        )

    def _offsets(
        self, air: Air, epoch: int, phase: str, senders: Sequence[int]
    ) -> npt.NDArray[np.int64]:
        """[ns] each frame's keyed start offset: its sender's in ``phase`` of ``epoch``."""
        key = np.asarray(senders, dtype=np.int64)
        ready = keyed_uniform(self.seed, int(Stream.AIR), START, epoch, PHASE_ORDER[phase], key)
        return np.floor(ready * round(air.start_spread_us * 1e3)).astype(np.int64)

    def _deadline_ns(self, phase: str) -> int:
        """[ns] ``phase``'s deadline from the epoch's start when it follows the others (its own
        window's length); the reports in the states' period are due at their deadline."""
        start, deadline = PHASES[phase]
        if phase == "report" and self.air.reports_with_states:
            start = 0.0
        return round((deadline - start) * self.period_s * 1e9)

    def _verdicts(
        self,
        out: PhaseOutcome,
        links: Sequence[Link],
        which: Sequence[int],
        first: int,
        frames: int,
        end_ns: int,
    ) -> list[AirVerdict]:
        """Each link's fate from ``out``: its frame ``first + which[p]`` at its receiver,
        late after ``end_ns``."""
        verdicts = []
        for p, (_, dst) in enumerate(links):
            f, r = first + which[p], self._node(dst)
            cause, arrival_ns = int(out.cause[f, r]), int(out.arrival_ns[f, r])
            if cause == Cause.DELIVERED and arrival_ns > end_ns:
                cause = Cause.LATE
            arrival = arrival_ns / 1e6 if cause == Cause.DELIVERED else math.nan
            name = "" if cause == Cause.DELIVERED else CAUSES[cause]
            verdicts.append(AirVerdict(name, arrival, int(out.attempts[f]), frames))
        return verdicts

    def _node(self, end: int) -> int:
        """A link end's row in the positions: agent ``i`` at ``i − 1``, the leader's at ``n``."""
        return self.n if end == LEADER_ENDPOINT else end - 1


def air_of(scenario: Scenario, seed: int, strategy: str | None = None) -> AirNetwork | None:
    """``scenario``'s air in a run of ``strategy`` (None: the scenario's), or None."""
    return AirNetwork(scenario, seed, strategy) if scenario.network.air is not None else None


class AirPlanner:
    """The simulator's air: epoch ``k``'s verdicts on the columns of a plan (links, then
    reports and estimates), given the positions the epoch loop computed."""

    def __init__(self, net: AirNetwork, links: npt.NDArray[np.int64]) -> None:
        self.net = net
        self.pairs = [(int(a), int(b)) for a, b in links.tolist()]
        self.by_phase = {
            phase: np.array(
                [
                    c
                    for c, lk in enumerate(self.pairs)
                    if packet_kind(lk)[0] == phase and net.carries(lk)
                ],
                dtype=np.int64,
            )
            for phase in PHASE_ORDER
        }

    def epoch(
        self, k: int, positions_m: npt.NDArray[np.float64], passed: npt.NDArray[np.bool_]
    ) -> npt.NDArray[np.int8]:
        """(L,) each column's cause code (``Cause``; 0: delivered or not on the air) for the
        packets ``passed`` (L,), from ``positions_m`` (n, d) [m]."""
        out = np.zeros(passed.shape, dtype=np.int8)
        cols = {
            phase: cols_all[passed[cols_all]].tolist() if cols_all.size else []
            for phase, cols_all in self.by_phase.items()
        }
        decided: list[tuple[list[int], list[AirVerdict]]] = []
        if self.net.reports_with_states:
            states, reports = cols.pop("state"), cols.pop("report")
            pairs = ([self.pairs[c] for c in states], [self.pairs[c] for c in reports])
            fates = self.net.with_states(k, *pairs, positions_m)
            decided += [(states, fates[0]), (reports, fates[1])]
        for phase, some in cols.items():
            if some:
                decided.append(
                    (some, self.net.phase(k, phase, [self.pairs[c] for c in some], positions_m))
                )
        for some, verdicts in decided:
            for c, v in zip(some, verdicts, strict=True):
                if v.cause:
                    out[c] = CAUSES.index(v.cause)
        return out


__all__ = ["AIR", "CAUSES", "AirNetwork", "AirPlanner", "AirVerdict", "air_of"]
