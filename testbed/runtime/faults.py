"""Unplanned faults during a run: who died, when, and whether it came back (issue 20).

An agent or the leader that exits with a non-zero code is a *loss*, not the run's end:
netem stops waiting for a dead sender, the rest of the team goes on, and with the
``on-failure`` policy (Compose's name) the launcher starts it again and it rejoins
(netem's ``netem/rejoin`` says from which epoch). netem, the router or the recorder
dying ends the run with an error naming the process; the recording is kept.
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import orjson

from formation.body import BODY_LOST_EXIT
from formation.errors import RunEnded, RuntimeFailure
from formation.plugin_api import PLUGIN_EXIT
from testbed.runtime.processes import Child, ProcessGroup
from testbed.runtime.restart_policy import RESTART_POLICIES, RestartPolicy

ESSENTIAL = ("router", "recorder", "netem")  # the run cannot go on without them
MAX_RESTARTS = 3  # per process: one that dies again at once is not restarted forever


def agent_ids(name: str) -> list[int]:
    """The agent ids of a process's name: ``agent-3`` → [3], ``pool-1-25`` → 1..25 (a
    restarted incarnation ``agent-3.1`` too)."""
    parts = [int(p) for p in name.split(".")[0].split("-")[1:]]
    return list(range(parts[0], parts[-1] + 1))


def check_restart(policy: RestartPolicy, robots: Sequence[int], mode: str) -> None:
    """Refuse ``on-failure`` for agents whose bodies are ROS 2 robots in realtime: such an
    agent is lost when its robot's pose stops, and a new process would wait on the same
    silent robot (a scenario's planned restarts do run: the robot is there)."""
    if policy == "on-failure" and robots and mode == "realtime":
        raise RuntimeFailure(
            f"--restart on-failure with ROS 2 robot bodies in realtime (agents "
            f"{', '.join(map(str, robots))}): an agent is lost when its robot's pose stops "
            "coming, and a new process would wait on the same silent robot; run without "
            "--restart (a lost robot's agent stays lost) or in lockstep"
        )


@dataclass
class Loss:
    """One process that died before the run's end, as the launcher saw it."""

    name: str  # agent-3, leader, pool-1-25
    pid: int
    code: int | None
    epoch: int  # the first epoch it did not finish (its state or estimate never came)
    after_start_s: float  # when the launcher saw it gone, from the start of epoch 0 [s]
    restarted_pid: int | None = None
    back_from_epoch: int | None = None  # first epoch recorded of it after the restart
    back_after_s: float | None = None  # from the loss to that epoch's record [s]

    def as_json(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class Incarnation:
    """The newest process of a role and what it was started as."""

    child: Child
    module: str
    args: tuple[str, ...]
    restarts: int = 0


class Supervisor:
    """Watches a run's processes between epochs: losses, restarts, the essential ones."""

    def __init__(self, group: ProcessGroup, policy: RestartPolicy, started: float) -> None:
        self.group, self.policy, self.started = group, policy, started
        self.begun = False  # epoch 0 has started (begin)
        self.current: dict[str, Incarnation] = {}
        self.losses: list[Loss] = []
        self.planned: set[int] = set()  # pids a crash event ended: not losses

    def kill_planned(self, name: str) -> None:
        """A crash event: ``name``'s process killed by PID, without a goodbye (issue 20)."""
        pid = self.current[name].child.pid
        self.planned.add(pid)
        os.kill(pid, signal.SIGKILL)

    def start_planned(self, name: str, module: str, *args: str) -> Child:
        """A join or restart event: a new process for ``name`` (it asks netem from when)."""
        inc = self.current.get(name)
        count = 0 if inc is None else inc.restarts + 1
        child = self.group.start(name if inc is None else f"{name}.e{count}", module, *args)
        self.current[name] = Incarnation(child, module, tuple(args), count)
        return child

    def track(self, child: Child, module: str, *args: str) -> None:
        self.current[child.name] = Incarnation(child, module, tuple(args))

    def check_starting(self) -> None:
        """While the team comes up: with ``on-failure`` an agent or the leader that died is
        started again, as mid-run (netem starts the run once the new one is up); without it,
        or after ``MAX_RESTARTS``, its death is the run's end, naming it and its log."""
        if self.policy == "on-failure":
            self.check(lambda name: 0)
        replaced = self.replaced()
        for name, inc in self.current.items():
            c, code = inc.child, inc.child.proc.poll()
            if code == PLUGIN_EXIT:
                raise RunEnded(plugin_reason(c), 0, "")
            if code in (None, 0) or c.pid in replaced or name in ESSENTIAL:
                continue  # an essential one is the waits' (and check's) to report
            hint = (
                f"it died {inc.restarts + 1} times"
                if self.policy == "on-failure"
                else "--restart on-failure starts it again"
            )
            raise RuntimeFailure(
                f"{c.name} (pid {c.pid}) exited with code {code} before the run started "
                f"({hint}); its log is {c.log_path}:\n{c.tail()}"
            )

    def replaced(self) -> set[int]:
        """PIDs of dead processes that were started again: no longer a reason to stop."""
        return {loss.pid for loss in self.losses if loss.restarted_pid is not None}

    def begin(self, at: float) -> None:
        """Epoch 0 starts at ``at``: losses seen while starting up are timed before it (< 0)."""
        for loss in self.losses:
            loss.after_start_s -= at - self.started
        self.started, self.begun = at, True

    def running(self, names: list[str] | None = None) -> bool:
        """Whether any current process other than the router and the recorder still runs."""
        return any(
            inc.child.proc.poll() is None
            for name, inc in self.current.items()
            if name not in ("router", "recorder") and (names is None or name in names)
        )

    def check(self, first_missing: Any) -> None:
        """Raise for a dead essential process; note (and restart) a dead agent or leader.

        ``first_missing(name)`` is the first epoch the launcher has not seen of ``name``.
        """
        for name, inc in list(self.current.items()):
            code = inc.child.proc.poll()
            if code is None or (code == 0 and name not in ESSENTIAL[:2]):
                continue
            c = inc.child
            if code == PLUGIN_EXIT:  # the user's code failed: no restart would mend it
                # it sent its epoch-k state, then failed stepping: k + 1 is the first missing;
                # netem failed on a packet of the newest epoch any agent sent a state of
                seen = int(first_missing(name if name not in ESSENTIAL[:2] else "leader"))
                raise RunEnded(plugin_reason(c), max(seen - 1, 0), "")
            if name in ESSENTIAL:
                what = "the Zenoh router" if name == "router" else name
                raise RuntimeFailure(
                    f"{what} (pid {c.pid}) exited with code {code}; the run cannot go on:\n{c.tail()}"
                )
            if c.pid in self.planned or any(loss.pid == c.pid for loss in self.losses):
                continue
            loss = Loss(
                name, c.pid, code, int(first_missing(name)), time.monotonic() - self.started
            )
            self.losses.append(loss)
            if self.policy == "on-failure" and inc.restarts < MAX_RESTARTS:
                inc.restarts += 1
                # into the running run; before its start a new process starts as any other
                rejoin = ("--rejoin",) if inc.module == "agent" and self.begun else ()
                new = self.group.start(f"{name}.{inc.restarts}", inc.module, *inc.args, *rejoin)
                inc.child, loss.restarted_pid = new, new.pid

    def check_team(self, agents: list[str]) -> None:
        """Raise once every agent process is gone for good: there is no team left."""
        gone = self.gone_for_good()
        if agents and set(agents) <= gone:
            lost = {x.name for x in self.losses if x.code == BODY_LOST_EXIT}
            names = ", ".join(
                f"{n}: its robot's pose stopped coming" if n in lost else n
                for n in sorted(gone & set(agents))
            )
            raise RuntimeFailure(f"every agent is gone ({names}); the run cannot go on")

    def gone_for_good(self) -> set[str]:
        """Names whose newest process died, was planned or noted by :meth:`check`, and was not
        started again. A death since the last check is the next check's.
        """
        noted = {loss.pid for loss in self.losses} | set(self.planned)
        return {
            name
            for name, inc in self.current.items()
            if inc.child.pid in noted
            and inc.child.proc.poll() not in (None, 0)
            and name not in ESSENTIAL
        }

    def note_returns(
        self,
        seen: npt.NDArray[np.bool_],
        returns: dict[int, tuple[int, float]],
        team_events: Sequence[tuple[float, str]] = (),
    ) -> None:
        """Settle each agent loss from what was recorded: the epoch it was lost at, and for a
        restarted one its first epoch back and how long after its loss it came.

        seen : (E + 1, n) states recorded; returns : agent → (epoch, monotonic time) of its
        first state after a gap; team_events : netem's running statuses (monotonic time,
        JSON detail), whose ``back`` names the epoch a restarted sender takes part from.
        """
        for loss in self.losses:
            if not loss.name.startswith("agent-"):
                continue
            i = int(loss.name.removeprefix("agent-"))
            col = seen[:, i - 1]
            back = None
            if loss.restarted_pid is not None:
                back = _netem_back(team_events, i, self.started + loss.after_start_s)
            # Its last states can reach the launcher after it saw the process gone; one lost
            # while starting up had none.
            late = len(col) if loss.after_start_s >= 0 else loss.epoch
            stop = late if back is None else back
            while loss.epoch < stop and col[loss.epoch]:
                loss.epoch += 1
            if loss.restarted_pid is None:
                continue
            later = np.flatnonzero(col[loss.epoch :])
            if back is None and len(later):
                back = loss.epoch + int(later[0])
            if back is not None and back < len(col) and col[back]:
                loss.back_from_epoch = back
                epoch, at = returns.get(i, (None, 0.0))
                if epoch == back:
                    loss.back_after_s = at - self.started - loss.after_start_s


def _netem_back(team_events: Sequence[tuple[float, str]], agent: int, since: float) -> int | None:
    """The epoch netem said ``agent`` takes part from, in its first team event after ``since``."""
    for t, detail in team_events:
        if t < since:
            continue
        try:
            back = orjson.loads(detail).get("back", {})
            if str(agent) in back:
                return int(back[str(agent)])
        except (orjson.JSONDecodeError, AttributeError, TypeError, ValueError):
            continue  # not a team event
    return None


def plugin_reason(child: Child) -> str:
    """What a process that exited with ``PLUGIN_EXIT`` said of its plug-in (its log's error line)."""
    lines = child.tail(40).splitlines()
    said = [line.split(": error: ", 1)[1] for line in lines if ": error: " in line]
    return (
        f"{child.name}: {said[-1]}"
        if said
        else f"{child.name}: a plug-in failed (see {child.log_path})"
    )


def first_missing_epoch(seen: npt.NDArray[np.bool_]) -> int:
    """The epoch after the last one seen (``seen``: (E + 1,) a state of each epoch came)."""
    got = np.flatnonzero(seen)
    return int(got[-1]) + 1 if len(got) else 0


__all__ = [
    "RESTART_POLICIES",
    "Loss",
    "RestartPolicy",
    "Supervisor",
    "agent_ids",
    "check_restart",
    "first_missing_epoch",
]
