"""The leader process: each epoch, the reports that netem delivered → tree, BLUE, rigidity → estimate."""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator
from dataclasses import replace
from functools import partial
from typing import Any

import numpy as np
import numpy.typing as npt
import orjson

from formation import keys
from formation.codec import attachment
from formation.deadlines import CAUSES, USED_KEPT, cause
from formation.errors import RuntimeFailure
from formation.messages import DeliveredPacket, Delivery, TokenReport
from formation.realtime import REPORT_DEADLINE, Clock
from formation.reference import reference_positions, reference_velocities
from formation.scenario import Scenario
from leader.epoch import Leader, LeaderEpoch
from leader.rigidity import HealthyRigidity
from shell import Incoming, Loop, Service, TimePolicy, Wait

log = logging.getLogger("leader")


def link_rows(scenario: Scenario) -> dict[tuple[int, int], int]:
    """``(sender, receiver)`` → row of the scenario's directed links."""
    return {(a, b): row for row, (a, b) in enumerate(scenario.directed_links.tolist())}


def reports_to_measurements(
    scenario: Scenario,
    reports: list[TokenReport],
    index: dict[tuple[int, int], int] | None = None,
) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.float64]]:
    """Reports → ``known`` (L,) and ``z`` (L, d) in the scenario's directed-link order.

    ``index``: :func:`link_rows` of the scenario, built once by a caller that asks every epoch.
    """
    links = scenario.directed_links
    index = link_rows(scenario) if index is None else index
    known = np.zeros(len(links), dtype=bool)
    z = np.zeros((len(links), scenario.dimension))
    for report in reports:
        for m in report.measurements:
            row = index.get((m.neighbour, report.agent))
            if (
                row is not None
                and m.token == 1
                and m.z is not None
                and len(m.z) == scenario.dimension
            ):
                known[row], z[row] = True, m.z
    return known, z


def estimate_message(
    head: dict[str, object],
    lead: LeaderEpoch,
    x_ref: list[float],
    v_ref: list[float],
    edges: npt.NDArray[np.int64],
    reports: int,
) -> bytes:
    """The whole :class:`LeaderEstimate` as JSON, built with orjson (at 1,000 agents the
    pydantic model cost 4 ms an epoch; a test checks the model validates every field).

    An epoch computed without covariances (``estimator.covariance_every``) has ``None`` for
    every agent's block."""
    res = lead.estimate
    observable = res.observable.tolist()
    blocks = [None] * len(observable) if res.covariances is None else res.covariances.tolist()
    return orjson.dumps(
        {
            **head,
            "kind": "estimate",
            "positions": [
                p if ok else None for p, ok in zip(res.positions.tolist(), observable, strict=True)
            ],
            "covariances": [c if ok else None for c, ok in zip(blocks, observable, strict=True)],
            "observable": observable,
            "tree": edges[lead.tree].tolist(),
            "healthy": edges[lead.healthy].tolist(),
            "components": int(lead.components),
            "rigidity_rank": int(lead.rigidity_rank),
            "rigid": bool(lead.rigid),
            "x_ref": x_ref,
            "v_ref": v_ref,
            "reports_received": reports,
        }
    )


def agent_estimates(
    scenario: Scenario, lead: LeaderEpoch, v_ref: list[float]
) -> Iterator[tuple[int, dict[str, Any]]]:
    """``(i, AgentEstimate fields)`` per agent: its in-neighbours' ``x̂`` and ``v_ref``.

    Plain dicts, sent with orjson: at 1,000 agents the leader sends 1,000 of them an epoch.
    The common header fields are the sender's to add.
    """
    res = lead.estimate
    positions = [
        p if ok else None
        for p, ok in zip(res.positions.tolist(), res.observable.tolist(), strict=True)
    ]
    for i, neighbours in enumerate(scenario.in_neighbours, start=1):
        yield (
            i,
            {
                "kind": "agent_estimate",
                "agent": i,
                "neighbours": neighbours,
                "positions": [positions[j - 1] for j in neighbours],
                "v_ref": v_ref,
            },
        )


class LeaderNode:
    """The leader's shell: netem's report deliveries in, estimates out, on the bus."""

    def __init__(self, service: Service, scenario: Scenario) -> None:
        self.service, self.scenario = service, scenario
        self.run_id = service.run_id
        period = scenario.control.period_s
        self.ref_x = reference_positions(
            scenario.reference,
            scenario.offsets[scenario.reference_agent - 1],
            period,
            scenario.epochs,
        )
        self.ref_v = reference_velocities(self.ref_x, period)
        self.reports: dict[tuple[int, int], TokenReport] = {}  # realtime: (agent, seq) → report
        self.deliveries: dict[int, Delivery] = {}  # lockstep: epoch → netem's reports of it
        self.epoch = 0
        self.rigidity = HealthyRigidity(scenario.offsets, scenario.edge_array)
        self.leader = Leader(scenario, self.rigidity)
        self.covariance_every = scenario.estimator.covariance_every
        self.link_rows = link_rows(scenario)
        self.late_reports = 0
        # realtime: epoch → agents whose report was used (a later copy is no miss)
        self.used_reports: dict[int, set[int]] = {}
        self.clock: Clock | None = None  # realtime: set by run
        # realtime: reports in time and missed by cause; estimates sent before the deadline
        self.deadline = {"in_time": 0, "early_estimates": 0, **dict.fromkeys(CAUSES, 0)}
        service.subscribe(keys.inbox(self.run_id, keys.LEADER_ENDPOINT, "report"))
        service.declare_publishers(
            [keys.leader_estimate_out(self.run_id)]
            + [keys.leader_estimate_for(self.run_id, i) for i in range(1, scenario.n + 1)]
        )
        service.watch_alive()

    def rejoin(self) -> int:
        """Restarted into a running run: netem says from which epoch (the reference's there)."""
        answer = self.service.ask(keys.netem_rejoin(self.run_id), {"leader": True})
        if answer is None:  # no netem to rejoin (e.g. a recording replayed into this leader)
            log.warning("a start token but no netem/rejoin answer: estimating from epoch 0")
            return self.epoch
        try:
            epoch = int(answer["leader"]["from_epoch"])
        except (KeyError, TypeError, ValueError):
            raise RuntimeFailure(
                f"leader: restarted into a running run, and netem did not say from which "
                f"epoch to take part (answer {answer!r})"
            ) from None
        log.warning("restarted: estimating again from epoch %d", epoch)
        self.epoch = epoch
        return epoch

    def _route(self, msg: Incoming) -> None:
        """Realtime: the reports netem forwarded at one wake-up; one of an epoch already
        estimated missed its deadline (counted by cause)."""
        delivery = self._delivery(msg)
        if delivery is None:
            return
        for _, report in self._reports(delivery.packets):
            if self.clock is not None and report.epoch < self.epoch:
                in_time = msg.arrived_ns <= self.clock.at(report.epoch, REPORT_DEADLINE)
                if in_time and report.agent in self.used_reports.get(report.epoch, ()):
                    continue  # a copy of one already used, in an estimate before the deadline
                # else late, or stamped in time but queued after the deadline's take (scheduling)
                self.late_reports += 1
                self.deadline[
                    cause(self.clock, "report", report.epoch, report.stamp_ns, msg.arrived_ns)
                ] += 1
            else:
                self.reports[(report.agent, report.seq)] = report

    def _delivery(self, msg: Incoming) -> Delivery | None:
        """netem's delivery of reports to the leader, or None (counted if it is not one)."""
        delivery = self.service.malformed.decode(msg.key, msg.payload, Delivery)
        if delivery is not None and (
            delivery.receiver != keys.LEADER_ENDPOINT or delivery.phase != "report"
        ):
            self.service.malformed.counts[msg.key] += 1  # not the leader's: unusable
            return None
        return delivery

    def _reports(
        self, packets: Iterable[DeliveredPacket]
    ) -> Iterator[tuple[DeliveredPacket, TokenReport]]:
        """The valid reports among ``packets``; the others counted on their links' keys."""
        return self.service.malformed.decode_packets(
            packets,
            TokenReport,
            lambda p: keys.link_report(self.run_id, p.source),
            lambda p, report: report.agent == p.source,
        )

    def _take_delivery(self, msg: Incoming) -> None:
        """Lockstep: keep netem's delivery of an epoch's reports until that epoch is estimated."""
        delivery = self._delivery(msg)
        if delivery is not None and delivery.epoch >= self.epoch:
            self.deliveries[delivery.epoch] = delivery

    def _delivered(self, k: int) -> bool:
        return k in self.deliveries

    def _delivered_reports(self, k: int) -> list[TokenReport]:
        """Lockstep: the reports of epoch ``k``'s delivery (a delayed one is not fused)."""
        delivery = self.deliveries.pop(k)
        current = (p for p in delivery.packets if p.sent_epoch == k)
        return [report for _, report in self._reports(current)]

    def _queued_reports(self, k: int) -> list[TokenReport]:
        """Realtime: the reports of epoch ``k`` that came by its deadline (kept: later ones')."""
        reports = [r for r in self.reports.values() if r.epoch == k]
        self.reports = {q: r for q, r in self.reports.items() if r.epoch > k}  # agents ahead
        self.deadline["in_time"] += len(reports)
        self.used_reports[k] = {r.agent for r in reports}
        self.used_reports.pop(k - USED_KEPT, None)
        return reports

    def _estimate(self, k: int, reports: list[TokenReport]) -> None:
        known, z = reports_to_measurements(self.scenario, reports, self.link_rows)
        # the estimates go out before the covariances are computed: agents never wait for them
        batch = self.leader.epochs(known[None], z[None], self.ref_x[k], covariances=False)
        lead = batch.member(0)
        if not lead.estimate.observable.all():
            log.info(
                "epoch %d: %d agents unobservable from the reference",
                k,
                int((~lead.estimate.observable).sum()),
            )
        v_ref = [float(v) for v in self.ref_v[k]]
        for i, fields in agent_estimates(self.scenario, lead, v_ref):
            key = keys.leader_estimate_for(self.run_id, i)
            head = self.service.header(key, k)
            att = attachment(k, int(head["seq"]), keys.LEADER_ENDPOINT)
            self.service.put(key, orjson.dumps({**head, **fields}), att)
        if k % self.covariance_every == 0:
            blocks = self.leader.covariances(known[None], z[None], self.ref_x[k], batch)[0]
            lead = replace(lead, estimate=replace(lead.estimate, covariances=blocks))
        key = keys.leader_estimate_out(self.run_id)
        head = self.service.header(key, k)
        msg = estimate_message(
            head,
            lead,
            [float(v) for v in self.ref_x[k]],
            v_ref,
            self.scenario.edge_array,
            len(reports),
        )
        self.service.put(key, msg, attachment(k, int(head["seq"]), keys.LEADER_ENDPOINT))
        self.epoch = k + 1

    def confirm_last(self) -> None:
        """Before the session closes, wait until netem has the last epoch's estimates (it
        answers once it has, or after a moment): the query also goes out after them."""
        answer = self.service.ask(keys.netem_final(self.run_id), {"estimates": True})
        done = None if answer is None else answer.get("estimates_done")
        if isinstance(done, int) and done < self.scenario.epochs:
            log.warning(
                "netem has handled estimates of %d epochs of %d", done, self.scenario.epochs
            )

    def _has_reports(self, epoch: int) -> bool:
        return len({r.agent for r in self.reports.values() if r.epoch == epoch}) == self.scenario.n

    def rehearse(self, times: int = 2) -> None:
        """An epoch's estimates from every link, computed and built but not sent, before the
        clock starts: first runs are slower (CPython specialises code as it runs it), and
        the first epoch is when every process pays that at once (AgentNode.rehearse)."""
        links = self.scenario.directed_links
        offsets = self.scenario.offsets
        known = np.ones(len(links), dtype=bool)
        z = offsets[links[:, 0] - 1] - offsets[links[:, 1] - 1]  # any formation will do
        head = {
            "run_id": self.run_id,
            "sender": self.service.name,
            "seq": 0,
            "epoch": 0,
            "stamp_ns": 0,
        }
        v_ref = [float(v) for v in self.ref_v[0]]
        for _ in range(times):
            batch = self.leader.epochs(known[None], z[None], self.ref_x[0], covariances=False)
            for _i, fields in agent_estimates(self.scenario, batch.member(0), v_ref):
                orjson.dumps({**head, **fields})
        # epoch 0's covariances come right after its estimates, while the agents step
        self.leader.covariances(known[None], z[None], self.ref_x[0], batch)

    def _epochs(self, timing: TimePolicy) -> Loop:
        """The one loop (docs/architecture.md "Time"): each epoch, the reports netem
        delivered (lockstep), or those that came by the report deadline (realtime), are
        estimated."""
        realtime = timing.realtime
        for k in range(self.epoch, self.scenario.epochs):
            # Realtime: once every agent's report is here nothing else of epoch k can come:
            # estimating then gives what the deadline would, and the agents and their states
            # more time.
            complete = partial(self._has_reports if realtime else self._delivered, k)
            self.deadline["early_estimates"] += yield Wait(k, REPORT_DEADLINE, complete)
            self._estimate(k, self._queued_reports(k) if realtime else self._delivered_reports(k))

    def run(self, timing: TimePolicy) -> int:
        """Estimate every epoch of the run under ``timing``; returns an exit code.

        Lockstep: reports are handled as they arrive, on the bus's thread, and this thread
        only watches; realtime: each period, the reports that arrived by the report deadline
        (later ones are lost, counted by cause).
        """
        if timing.realtime:
            self.rehearse()  # while the others start: the clock is not running yet
        if not timing.join(self.service):
            return 1
        self.clock = timing.clock
        route = self._route if timing.realtime else self._take_delivery
        return timing.drive(self.service, self._epochs(timing), route, self.scenario.epochs)
