"""The leader process: each epoch, the reports that netem delivered → tree, BLUE, rigidity → estimate."""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from formation import keys
from formation.codec import attachment, now_ns
from formation.deadlines import CAUSES, ROBOT_SILENT
from formation.errors import RuntimeFailure
from formation.messages import TokenReport
from formation.reference import reference_positions, reference_velocities
from formation.scenario import Scenario
from leader.epoch import Leader
from leader.rigidity import HealthyRigidity
from leader.wire import (
    EstimateParts,
    LinkIndex,
    estimate_message,
    position_rows,
    reports_to_measurements,
)
from shell import Loop, PhaseInbox, Service, TimePolicy

log = logging.getLogger("leader")


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
        self.links = LinkIndex(scenario.directed_links, scenario.n)
        self.parts = EstimateParts(scenario.in_neighbours, service.header_format())
        self.part_keys = [
            keys.leader_estimate_for(self.run_id, i) for i in range(1, scenario.n + 1)
        ]
        self.part_seq = 0  # the seq of every agent's part key: they all move once an epoch
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
        known, z = reports_to_measurements(self.scenario, reports, self.links)
        # On the tree the covariances are path sums beside the positions' and cost little:
        # computed with them. On a cyclic graph they come after the estimates have gone out,
        # so that agents never wait for them.
        due = k % self.covariance_every == 0
        together = due and self.leader.on_tree
        batch = self.leader.epochs(known[None], z[None], self.ref_x[k], covariances=together)
        lead = batch.member(0)
        if not lead.estimate.observable.all():
            log.info(
                "epoch %d: %d agents unobservable from the reference",
                k,
                int((~lead.estimate.observable).sum()),
            )
        v_ref = [float(v) for v in self.ref_v[k]]
        rows = position_rows(lead.estimate.positions, lead.estimate.observable)
        self._send_parts(k, rows, v_ref)
        if due and not together:
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
            rows,
        )
        self.service.put(key, msg, attachment(k, int(head["seq"]), keys.LEADER_ENDPOINT))
        self.epoch = k + 1

    def _send_parts(self, k: int, rows: list[bytes], v_ref: list[float]) -> None:
        """Each agent's part of epoch ``k``'s estimate, each with its own key's header: on
        that key (realtime), or all in one :class:`~formation.messages.Bundle` (lockstep)."""
        service, seq, stamp_ns = self.service, self.part_seq, now_ns()
        self.part_seq += 1
        if not self.bundled:
            texts = self.parts.texts(rows, v_ref, k, stamp_ns, seq)
            sent = attachment(k, seq, keys.LEADER_ENDPOINT)
            for key, text in zip(self.part_keys, texts, strict=True):
                service.put(key, text, sent)
            return
        key = keys.leader_estimates(self.run_id)
        head = service.header(key, k)
        msg = self.parts.bundle(head, rows, v_ref, k, stamp_ns, seq)
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
        v_ref = [float(v) for v in self.ref_v[0]]
        head = {"run_id": self.run_id, "sender": self.service.name, "seq": 0, "epoch": 0}
        for _ in range(times):
            batch = self.leader.epochs(known[None], z[None], self.ref_x[0], covariances=False)
            res = batch.member(0).estimate
            rows = position_rows(res.positions, res.observable)
            if self.bundled:
                self.parts.bundle({**head, "stamp_ns": 0}, rows, v_ref, 0, 0, 0)
            else:
                self.parts.texts(rows, v_ref, 0, 0, 0)
        # epoch 0's covariances come right after its estimates, while the agents step
        self.leader.covariances(known[None], z[None], self.ref_x[0], batch)

    def _epochs(self, inbox: PhaseInbox) -> Loop:
        """The one loop (docs/architecture.md "Time"): each epoch, the reports netem
        delivered are estimated."""
        for k in range(self.epoch, self.scenario.epochs):
            # Realtime: once every agent's report is here nothing else of epoch k can come:
            # estimating then gives what the deadline would, and the agents and their states
            # more time.
            got = yield from inbox.take_columns("report", k, self.scenario.n, "early_estimates")
            self._estimate(k, [got.payloads[e] for e in got.entry.tolist()])
            # freed now, after the estimates went out, rather than when the next epoch's
            # reports come (a thousand reports are some twenty thousand objects)
            del got

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
