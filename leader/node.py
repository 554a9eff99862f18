"""The leader process: each epoch, the reports that netem delivered → tree, BLUE, rigidity → estimate."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import replace
from typing import Any

import numpy as np
import numpy.typing as npt
import orjson

from formation import keys
from formation.codec import attachment
from formation.deadlines import CAUSES, ROBOT_SILENT
from formation.errors import RuntimeFailure
from formation.messages import TokenReport
from formation.reference import reference_positions, reference_velocities
from formation.scenario import Scenario
from leader.epoch import Leader, LeaderEpoch
from leader.rigidity import HealthyRigidity
from shell import Loop, PhaseInbox, Service, TimePolicy

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
        self.inbox: PhaseInbox | None = None  # the time policy's, from the run's start
        self.epoch = 0
        self.rigidity = HealthyRigidity(scenario.offsets, scenario.edge_array)
        self.leader = Leader(scenario, self.rigidity)
        self.covariance_every = scenario.estimator.covariance_every
        self.link_rows = link_rows(scenario)
        # realtime: reports in time and missed by cause; estimates sent before the deadline
        self.deadline = {
            "in_time": 0,
            "early_estimates": 0,
            **dict.fromkeys(CAUSES, 0),
            ROBOT_SILENT: 0,
        }
        service.subscribe(keys.inbox(self.run_id, keys.LEADER_ENDPOINT, "report"))
        # Lockstep: the agents' parts go as one bundle (netem splits it); realtime: one each.
        self.bundled = scenario.runtime.mode != "realtime"
        parts = [] if self.bundled else range(1, scenario.n + 1)
        service.declare_publishers(
            [keys.leader_estimate_out(self.run_id), keys.leader_estimates(self.run_id)]
            + [keys.leader_estimate_for(self.run_id, i) for i in parts]
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
        self._send_parts(k, agent_estimates(self.scenario, lead, v_ref))
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

    def _send_parts(self, k: int, parts: Iterator[tuple[int, dict[str, Any]]]) -> None:
        """Each agent's part of epoch ``k``'s estimate, each with its own key's header: on
        that key (realtime), or all in one :class:`~formation.messages.Bundle` (lockstep)."""
        service, run_id = self.service, self.run_id
        bundle = []
        for i, fields in parts:
            key = keys.leader_estimate_for(run_id, i)
            head = service.header(key, k)
            msg = orjson.dumps({**head, **fields})
            if self.bundled:
                bundle.append({"agent": i, "seq": head["seq"], "message": msg.decode()})
            else:
                service.put(key, msg, attachment(k, int(head["seq"]), keys.LEADER_ENDPOINT))
        if self.bundled:
            key = keys.leader_estimates(run_id)
            head = service.header(key, k)
            msg = orjson.dumps({**head, "kind": "bundle", "phase": "estimate", "parts": bundle})
            service.put(key, msg, attachment(k, int(head["seq"]), keys.LEADER_ENDPOINT))

    def confirm_last(self) -> None:
        """Before the session closes, wait until netem has the last epoch's estimates (it
        answers once it has, or after a moment): the query also goes out after them."""
        answer = self.service.ask(keys.netem_final(self.run_id), {"estimates": True})
        done = None if answer is None else answer.get("estimates_done")
        if isinstance(done, int) and done < self.scenario.epochs:
            log.warning(
                "netem has handled estimates of %d epochs of %d", done, self.scenario.epochs
            )

    def rehearse(self, times: int = 2) -> None:
        """An epoch's estimates from every link, computed and built but not sent, before the
        clock starts (:meth:`shell.TimePolicy.join`)."""
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

    def _epochs(self, inbox: PhaseInbox) -> Loop:
        """The one loop (docs/architecture.md "Time"): each epoch, the reports netem
        delivered are estimated."""
        for k in range(self.epoch, self.scenario.epochs):
            # Realtime: once every agent's report is here nothing else of epoch k can come:
            # estimating then gives what the deadline would, and the agents and their states
            # more time.
            reports = yield from inbox.take("report", k, self.scenario.n, "early_estimates")
            self._estimate(k, [report for _, report in reports[keys.LEADER_ENDPOINT]])

    def run(self, timing: TimePolicy) -> int:
        """Estimate every epoch of the run under ``timing``; returns an exit code.

        Lockstep: reports are handled as they arrive, on the bus's thread, and this thread
        only watches; realtime: each period, the reports that arrived by the report deadline
        (later ones are lost, counted by cause).
        """
        self.inbox = timing.inbox(self.service, [keys.LEADER_ENDPOINT], self.deadline)
        if not timing.join(self.service, self.rehearse):
            return 1
        loop = self._epochs(self.inbox)
        return timing.drive(self.service, loop, self.inbox.route, self.scenario.epochs)
