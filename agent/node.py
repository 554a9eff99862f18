"""The agent process: one agent, or a pool of agents sharing one bus session (``--ids``).

One loop, under a time policy (:mod:`shell.timing`, docs/architecture.md "Time"): publish
``x_i[k]``; take the states from the phase inbox (:mod:`shell.inbox`); report tokens and
measurements; take the estimate the same way; step to ``x_i[k+1]``. A pool takes each phase for all its agents
at once, in one vectorised step (the leader waits for every report anyway, so this costs
no time)."""

from __future__ import annotations

import copy
import json
import logging
import threading
import time
from typing import Any

import numpy as np

from agent.body import FIRST_POSE_S, RobotBodies
from agent.control import body_velocity
from agent.incoming import delivered_estimates, delivered_states
from agent.outgoing import Reports, state_messages, states_bundle
from agent.runner import AgentRunner
from formation import keys
from formation.body import BODY_LOST_EXIT
from formation.codec import attachment, now_ns
from formation.deadlines import CAUSES, PHASES, ROBOT_SILENT, SLACK
from formation.errors import BodyLost, RuntimeFailure
from formation.messages import CoordinationState, TokenReport
from formation.realtime import ESTIMATE_DEADLINE, STATE_DEADLINE
from formation.scenario import Scenario, StrategyName
from shell import Loop, PhaseInbox, Service, TimePolicy

log = logging.getLogger("agent")
WATCH_S = 0.25  # how often the main thread looks for netem's liveliness and a signal
DECLARE_POOL_S = 30.0  # how long a pool asks netem to batch its deliveries (netem may start late)


class AgentNode:
    """Drives one :class:`AgentRunner` (one agent or a pool) from the bus's traffic, phase by phase."""

    def __init__(
        self,
        service: Service,
        scenario: Scenario,
        ids: list[int],
        strategy: StrategyName,
        seed: int,
        bodies: RobotBodies | None = None,
    ) -> None:
        self.service, self.scenario = service, scenario
        self.bodies = bodies  # the agents whose body is a ROS 2 robot (agent.body)
        self.body_lost: BodyLost | None = None
        # realtime: this agent waited for its robot's pose and has not been in time since
        self.robot_waited = False
        self._timing: TimePolicy | None = None
        self._placed = False  # the bodies' poses taken as the agents' states
        self.cpu_at_start_s = 0.0
        self.run_id = service.run_id
        self.runner = AgentRunner(scenario, ids, strategy, seed)
        self.inbox: PhaseInbox | None = None  # the time policy's, from the run's start
        self.finished = threading.Event()  # the last epoch is done: the watching thread leaves
        self.end = scenario.epochs  # lockstep: the epoch of this process's last state
        self.deadline = {
            "packets": 0,
            "late_packets": 0,
            "estimates": 0,
            "late_estimates": 0,
            "overruns": 0,
            "early_steps": 0,  # steps before the estimate deadline: every estimate was in
            "in_time": 0,
            **dict.fromkeys(CAUSES, 0),
            ROBOT_SILENT: 0,
        }
        # Realtime: queued, taken at each deadline (Service.take_by); lockstep: a pool handles
        # each delivery on Zenoh's thread.
        direct = self.batched = len(ids) > 1 and scenario.runtime.mode != "realtime"
        for i in ids:
            # Exact keys, no wildcard: Zenoh finds an exact key's subscribers in its key
            # tree, while a wildcard is matched against every sample (a pool of 125 spent
            # a third of its CPU there).
            for phase in ("state", "estimate"):
                service.subscribe(keys.inbox(self.run_id, i, phase), direct=direct)
        if self.batched:  # lockstep: netem batches a declared pool's deliveries
            for phase in ("state", "estimate"):
                service.subscribe(keys.inbox_pool(self.run_id, ids[0], phase), direct=True)
            service.declare_publishers(
                [
                    keys.pool_states(self.run_id, ids[0]),
                    keys.pool_bundle(self.run_id, ids[0], "report"),
                ]
            )
        self.bundled = False  # states and reports go as bundles: netem took the declaration
        # each agent's state and report keys, built once: a pool puts hundreds an epoch
        self.own_keys = {
            i: (keys.agent_state(self.run_id, i), keys.agent_report(self.run_id, i)) for i in ids
        }
        service.declare_publishers(key for pair in self.own_keys.values() for key in pair)
        self._state_keys = [self.own_keys[i][0] for i in ids]  # in the agents' order
        self._report_keys = [self.own_keys[i][1] for i in ids]
        self._head = service.header_format()
        links = self.runner.links
        self._reports = Reports(ids, links.receiver.tolist(), links.sender.tolist())
        service.watch_alive()

    @property
    def done(self) -> bool:
        return self.finished.is_set()

    @property
    def last_epoch(self) -> int:
        """The epoch of this process's last state: the end of the run, or a leave or crash
        the scenario's events give (``formation.events``)."""
        k, team = self.runner.epoch, self.scenario.membership
        ends = [
            last for i in self.ids for first, last in team.incarnations(i) if first <= k <= last
        ]
        return min(ends, default=self.scenario.epochs)

    @property
    def crashes(self) -> bool:
        """Whether this process's part ends in a crash event (it then waits to be killed)."""
        k = self.last_epoch
        return k < self.scenario.epochs and bool(
            self.scenario.membership.crashed[k, [i - 1 for i in self.ids]].any()
        )

    @property
    def ids(self) -> list[int]:
        return self.runner.ids

    def announce(self) -> None:
        """Declare the pool's agents to netem (lockstep), then each agent alive: netem
        starts the run once every agent is, so it knows every pool by then."""
        if self.batched:
            self.declare_pool()
        for i in self.ids:
            self.service.announce("agent", i)

    def declare_pool(self) -> None:
        """Ask netem to batch these agents' deliveries (``netem/pool``) until it answers. The
        pool also listens on each agent's own keys: without an answer they come one by one."""
        key, ask = keys.netem_pool(self.run_id), {"pool": self.ids[0], "agents": self.ids}
        deadline = time.monotonic() + DECLARE_POOL_S
        while (answer := self.service.ask(key, ask)) is None:
            if self.service.stopping.wait(0.05) or time.monotonic() > deadline:
                log.warning("netem did not take this pool's declaration: messages one by one")
                return
        self.bundled = answer.get("batched") is True  # netem takes this pool's bundles

    def rejoin(self) -> int:
        """Restarted into a running run: ask netem from which epoch these agents take part
        and where their bodies are (its last forwarded states); returns that epoch."""
        answer = self.service.ask(keys.netem_rejoin(self.run_id), {"agents": self.ids})
        # A scheduled join or restart (scenario events) is answered once the run is near it.
        while (
            isinstance(answer, dict) and answer.get("wait") and not self.service.stopping.is_set()
        ):
            answer = self.service.ask(keys.netem_rejoin(self.run_id), {"agents": self.ids})
        try:
            if answer is None:
                raise KeyError("no answer")
            given = {i: answer["agents"][str(i)] for i in self.ids}
            epochs = {int(g["from_epoch"]) for g in given.values()}
            positions = {
                i: None if g["state"] is None else [float(v) for v in g["state"]["position"]]
                for i, g in given.items()
            }
            headings = {
                i: None
                if g["state"] is None or g["state"].get("heading") is None
                else float(g["state"]["heading"])
                for i, g in given.items()
            }
        except (KeyError, TypeError, ValueError):
            raise RuntimeFailure(
                f"{self.service.name}: restarted into a running run, and netem did not say "
                f"from which epoch to take part (answer {answer!r})"
            ) from None
        if len(epochs) != 1:
            raise RuntimeFailure(f"{self.service.name}: netem gave a pool several epochs {epochs}")
        (epoch,) = epochs
        self.runner.resume(epoch, positions, headings)
        log.warning("restarted: taking part again from epoch %d at %s", epoch, positions)
        return epoch

    # -- publishing -------------------------------------------------------------------------------
    def _robot_silent(self, kind: str) -> bool:
        """Whether a ``kind`` packet of this epoch sent now is late only because this agent
        waited for its robot's pose (realtime): marked so, its receivers count it as the
        robot's, not as the testbed's miss. The first packet in time ends the mark."""
        if not self.robot_waited or self._timing is None:
            return False
        self.robot_waited = self._timing.past(self.runner.epoch, PHASES[kind][0] + SLACK)
        return self.robot_waited

    def _publish_states(self, ids: list[int] | None = None) -> None:
        """Each agent's state, with its own key's seq: on that key, or (a declared pool in
        lockstep, every agent) all in one :class:`~formation.messages.Bundle`; a republished
        final state goes on its own key."""
        runner, agents = self.runner, self.ids if ids is None else ids
        k, silent = runner.epoch, self._robot_silent("state")
        state_keys = self._state_keys if ids is None else [self.own_keys[i][0] for i in agents]
        seqs = list(map(self.service.next_seq, state_keys))
        rows = runner.rows(np.array(agents, dtype=np.int64))
        poses = runner.poses(agents)
        substituted = [runner.substituted[i] for i in agents]
        stamp_ns, x = now_ns(), runner.x[rows]
        if self.bundled and ids is None:
            key = keys.pool_states(self.run_id, self.ids[0])
            seq = self.service.next_seq(key)
            msg = states_bundle(
                self._head, seq, k, stamp_ns, agents, seqs, x, substituted, poses, silent
            )
            self.service.put(key, msg, attachment(k, seq, self.ids[0]))
        else:
            messages = state_messages(
                self._head, seqs, k, stamp_ns, agents, x, substituted, poses, silent
            )
            self._put_each(state_keys, seqs, agents, messages)

    def _publish_reports(self) -> None:
        """Each agent's report, with its own key's seq: on that key, or (a declared pool
        in lockstep) all in one :class:`~formation.messages.Bundle`."""
        runner, k, silent = self.runner, self.runner.epoch, self._robot_silent("report")
        report_keys = self._report_keys
        seqs = list(map(self.service.next_seq, report_keys))
        stamp_ns, arrived, z = now_ns(), runner.arrived, runner.z
        if self.bundled:
            key = keys.pool_bundle(self.run_id, self.ids[0], "report")
            seq = self.service.next_seq(key)
            msg = self._reports.bundle(self._head, seq, k, stamp_ns, seqs, arrived, z, silent)
            self.service.put(key, msg, attachment(k, seq, self.ids[0]))
        else:
            messages = self._reports.messages(self._head, seqs, k, stamp_ns, arrived, z, silent)
            self._put_each(report_keys, seqs, self.ids, messages)

    def _put_each(
        self, own: list[str], seqs: list[int], agents: list[int], messages: list[bytes]
    ) -> None:
        k = self.runner.epoch
        for key, seq, i, msg in zip(own, seqs, agents, messages, strict=True):
            self.service.put(key, msg, attachment(k, seq, i))

    def confirm_final(self, timeout_s: float = 10.0) -> bool:
        """Republish what netem says it lacks of our final states, until it has them all.

        Called last, before the session closes (the query also goes out after everything
        published before it). False if netem did not answer: it has finished (so it had
        them) or is gone, which the launcher reports on its own.
        """
        deadline = time.monotonic() + timeout_s
        key = keys.netem_final(self.run_id)
        while True:
            answer = self.service.ask(key, {"agents": self.ids})
            lacks = None if answer is None else answer.get("missing")
            if not isinstance(lacks, list):
                return False  # no answer, or not one we can read (counted by ask)
            missing = [i for i in lacks if i in self.runner.row]
            if not missing:
                return True
            log.warning("netem lacks the final states of agents %s: publishing them again", missing)
            self._publish_states(missing)
            if time.monotonic() > deadline:
                log.error("netem still lacks the final states of agents %s", missing)
                return False

    # -- the loop ---------------------------------------------------------------------------------
    def _epochs(self, timing: TimePolicy, inbox: PhaseInbox) -> Loop:
        """The one loop (docs/architecture.md "Time"): publish ``x[k]``; take the states netem
        passed and report; take the estimate and step to ``x[k+1]``. A pool takes each
        phase for all its agents at once."""
        realtime = timing.realtime  # a robot's body moves by the mode (_move_bodies)
        self._timing = timing
        # realtime: x[k] (x[0], or a join's or restart's first) when later states go out
        timing.sleep_until(self.runner.epoch - 1, ESTIMATE_DEADLINE)
        self._publish_states()
        while self.runner.epoch < self.end:
            k = self.runner.epoch
            self.deadline["overruns"] += timing.past(k, STATE_DEADLINE)
            states = yield from inbox.take_columns("state", k)
            self.runner.receive(*delivered_states(states, self.scenario.dimension))
            self._publish_reports()
            # Realtime: stepping once every estimate here is in gives the step what the
            # deadline would (only epoch k's estimate counts) and the states more time: woken
            # at once at the deadline, 20 agents stepped one after another on 2 cores, the
            # last ones late.
            estimates = yield from inbox.take_columns("estimate", k, expect=1, early="early_steps")
            before = None if self.bodies is None else self.runner.x.copy()
            if realtime and self.bodies is not None:
                self._take_headings()  # a unicycle steps from where it faces now
            self.runner.step(*delivered_estimates(estimates, self.runner))
            # x[k+1] is known now: out at once, so the states have the rest of this period
            # as well as the next one's first 0.2 to arrive. In realtime it does not depend on
            # the robots' poses, so a wait for a robot's pose never makes it late.
            if realtime:
                if self.runner.epoch == self.end and self.crashes:
                    self._part_counts()  # before x[c]: once it is seen, this process is killed
                self._publish_states()
            if before is not None:
                try:
                    self._move_bodies(k, before, realtime)
                except BodyLost as exc:  # as a crash: this agent takes no further part
                    log.error("%s", exc)
                    self.body_lost = exc
                    break
            if not realtime:  # lockstep: x[k+1] is the robot's pose of k + 1
                self._publish_states()
        if realtime and self.bodies is not None and self.body_lost is None:
            self._record_last_poses()
        self.finished.set()

    def _part_counts(self) -> None:
        """Realtime, a crash event at the next epoch: this part's deadline counts as a final
        status, complete (nothing is sent to an agent at its crash's epoch), for the run's
        books; a restart is another part, with its own (testbed.runtime.observer)."""
        counts = self.deadline | ({} if self.bodies is None else self.bodies.status_counts())
        self.service.status("done", self.end, json.dumps(counts))

    def _record_last_poses(self) -> None:
        """Realtime: the robots' poses at the run's end, into the recording as their measured
        ``x[E]`` (each step records the pose it stepped from: the measured ``x[k]``)."""
        assert self.bodies is not None
        try:
            self.bodies.wait_poses(None, self.scenario.body.pose_timeout_s)
        except BodyLost as exc:
            log.error("%s", exc)
            return
        self._record_traffic(self.runner.epoch, ("pose",))

    def _take_headings(self) -> None:
        """A unicycle robot's newest heading as ``θ[k]`` (realtime)."""
        assert self.bodies is not None
        if self.runner.heading is not None:
            for i, heading in self.bodies.headings().items():
                self.runner.heading[self.runner.row[i]] = heading

    def _move_bodies(self, k: int, before: Any, realtime: bool) -> None:
        """Send each robot the velocity to its ``x[k+1]`` over one period (agent.body).

        Lockstep: ``x[k+1]`` is then the robot's pose stamped ``k + 1``. Realtime: the
        velocity goes from the robot's newest pose, and ``x[k+1]`` is where it leads: a robot
        reaches it as the next step comes, while a pose taken now would be a period old by
        then (a one-epoch delay in the consensus: 5 robots at 10 Hz went unstable).
        """
        assert self.bodies is not None
        ids = self.bodies.ids
        rows = [self.runner.row[i] for i in ids]
        timeout_s = self.scenario.body.pose_timeout_s
        if realtime:
            period_s = self.scenario.runtime.realtime_period_s or self.scenario.control.period_s
            waits = self.bodies.counts["stale_waits"]
            now = self.bodies.wait_poses(None, timeout_s)
            self.robot_waited |= self.bodies.counts["stale_waits"] > waits
            start = np.array([now[i] for i in ids], dtype=float)
            u = body_velocity(start, self.runner.x[rows], period_s)
            self.bodies.command(dict(zip(ids, u.tolist(), strict=True)))
        elif self.bodies.stepped:  # a unicycle: its inner loop, pose by pose (agent.steering)
            assert self.runner.drive is not None
            self.bodies.steer(k, dict(zip(ids, self.runner.drive[rows].tolist(), strict=True)))
            self.runner.place(*self.bodies.wait_steered(timeout_s))
        else:
            u = body_velocity(before[rows], self.runner.x[rows], self.scenario.control.period_s)
            self.bodies.command(dict(zip(ids, u.tolist(), strict=True)))
            self.runner.place(self.bodies.wait_poses(k + 1, timeout_s))
        self._record_traffic(k)

    def _record_traffic(self, k: int, kinds: tuple[str, ...] = ("pose", "command")) -> None:
        """Into the recording: each robot's pose taken and command sent (agent.body)."""
        assert self.bodies is not None
        # realtime: a pose's sequence is its epoch, so the recording matches poses to epochs
        # across a restart's parts too (recorder.reading.bodies)
        by_epoch = self._timing is not None and self._timing.realtime
        for i in self.bodies.ids:
            for what, type_name, cdr in self.bodies.traffic(i):
                if what in kinds:
                    key = keys.body(self.run_id, i, what, type_name)
                    seq = self.service.next_seq(key)
                    seq = k if by_epoch and what == "pose" else seq
                    self.service.put(key, cdr, attachment(k, seq, i))

    def run(self, timing: TimePolicy) -> int:
        """Run every agent to its last epoch under ``timing``; returns an exit code.

        Lockstep: deliveries are handled as they arrive, on the bus's thread, and this
        thread only watches; realtime: a fixed period, and what has not arrived by a
        phase's deadline is lost.
        """
        self.place_bodies(timing.realtime)
        self.inbox = timing.inbox(self.service, self.ids, self.deadline)
        if not timing.join(self.service, self.rehearse):
            return 1
        self.cpu_at_start_s = time.process_time()  # the run's CPU, from its start (agent.__main__)
        self.end = self.last_epoch  # the run's end, or its part's by the scenario's events
        loop = self._epochs(timing, self.inbox)
        code = timing.drive(self.service, loop, self.inbox.route, self.end)
        if self.body_lost is not None:
            return BODY_LOST_EXIT
        if code == 0 and self.crashes:
            # a crash event: no goodbye, no final status
            log.warning("crash at epoch %d (a scenario event): taking no further part", self.end)
            self.service.stopping.wait()
            return 130
        return code

    def place_bodies(self, realtime: bool) -> None:
        """``x[0]`` (or a restart's ``x[k]``) where the robots are, once each has sent a pose,
        checked, and its command topic is matched: before the agents are announced, so that a
        run never starts with an agent that has no pose. Once; raises what stops the agent."""
        if self.bodies is None or self._placed:
            return
        self._placed = True
        poses = self.bodies.wait_poses(None if realtime else 0, FIRST_POSE_S)
        if self.runner.epoch == 0:  # where the scenario starts them, not a restart's
            self.bodies.check_start({i: self.runner.position(i) for i in self.bodies.ids})
        if self.bodies.stepped:  # a unicycle's x[k], θ[k] as its inner loop takes them
            assert self.runner.heading is not None
            rows = {i: self.runner.row[i] for i in self.bodies.ids}
            expected = {
                i: (self.runner.x[r].tolist(), float(self.runner.heading[r]))
                for i, r in rows.items()
            }
            self.runner.place(*self.bodies.settle(expected))
        else:
            self.runner.place(poses)
            self._take_headings()
        self.bodies.wait_subscribed(FIRST_POSE_S)

    def rehearse(self, times: int = 3) -> None:
        """This process's own work of an epoch, on a copy of its agents, before the clock
        starts (:meth:`shell.TimePolicy.join`). Nothing is published; the copy is dropped."""
        runner = copy.deepcopy(self.runner)
        a, d, links = len(self.ids), self.scenario.dimension, runner.links
        for _ in range(times):
            k = runner.epoch
            poses = runner.poses(self.ids)
            states = state_messages(self._head, [0] * a, k, 0, self.ids, runner.x, [[]] * a, poses)
            read = {
                i: CoordinationState.model_validate_json(m)
                for i, m in zip(self.ids, states, strict=True)
            }
            # each in-link a state, as the receiver's own would read
            positions = np.array([read[i].position for i in links.receiver.tolist()])
            sent = np.full(len(links.index), k)
            runner.receive(links.receiver, links.sender, sent, positions.reshape(-1, d))
            for m in self._reports.messages(self._head, [0] * a, k, 0, runner.arrived, runner.z):
                TokenReport.model_validate_json(m)
            n_links = len(links.index)
            runner.step(
                np.zeros((a, d)), np.zeros(a, bool), np.zeros((n_links, d)), np.zeros(n_links, bool)
            )
