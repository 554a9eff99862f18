"""The scenario's events carried out on real processes (issue 20 item 1).

netem and the agents derive who takes part at each epoch from the scenario
(``formation.events``), so what each process does at an event is fixed by its epoch: an agent
publishes its last state ``x[c]`` at a leave (its goodbye, then it exits) or a crash (then it
waits). The launcher's part is the processes themselves:

* a crash: once the agent's ``x[c]`` is seen (netem keeps it as the body's state), its process
  is killed by PID with SIGKILL, no goodbye; the supervisor does not count it as a loss;
* a join or a restart at ``r``: a new process is started a little before the run reaches ``r``
  (``lead_s`` at the current rate: in realtime the clock's, and a first join's with the
  others, at the start); it asks netem's ``netem/rejoin``.
  In lockstep netem answers once the run is at ``r − 1`` with ``r`` and, for a restart, the
  body's state; netem waits for its ``x[r]`` as for anyone's, so a late start costs time,
  never a different run. In realtime netem answers at once, from the clock: ``r`` if it is
  still ahead, else two epochs after the one under way (a start that took longer than the
  lead is late, as a real process would be), with the last state it forwarded.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from formation.errors import RuntimeFailure
from formation.scenario import Scenario
from testbed.runtime.faults import Supervisor

LEAD_S = 3.0  # [s] a (re)started process needs about 1 s to come up on a loaded machine


@dataclass
class Step:
    """One thing the launcher does: ``kill`` agent's process after ``x[epoch]``, or ``start`` one."""

    epoch: int
    action: str  # "kill" or "start"
    agent: int
    done: bool = False


class EventDriver:
    """Kills and starts agent processes as the scenario's events say, from the run's progress."""

    def __init__(
        self,
        scenario: Scenario,
        supervisor: Supervisor,
        agent_args: Callable[[int], list[str]],
        lead_s: float = LEAD_S,
    ) -> None:
        self.team, self.epochs = scenario.membership, scenario.epochs
        runtime = scenario.runtime  # realtime: the rate is the clock's, not a measurement
        self.period_s = (
            (runtime.realtime_period_s or scenario.control.period_s)
            if runtime.mode == "realtime"
            else None
        )
        self.supervisor, self.agent_args, self.lead_s = supervisor, agent_args, lead_s
        self.steps: list[Step] = []
        for i in range(1, scenario.n + 1):
            for part, (first, last) in enumerate(self.team.incarnations(i)):
                if first > 0 and (part > 0 or self.period_s is None):
                    self.steps.append(Step(first, "start", i))
                if last < self.epochs and self.team.crashed[last, i - 1]:
                    self.steps.append(Step(last, "kill", i))
        self.steps.sort(key=lambda s: (s.epoch, s.action != "kill"))
        self.began = time.monotonic()

    @staticmethod
    def check(scenario: Scenario, pool: int | None) -> None:
        """Events need one process per agent: a pool shares one process between agents."""
        if scenario.events and pool:
            raise RuntimeFailure(
                f"--pool {pool} with scenario events: an event stops or starts one agent's "
                "process, so run one process per agent (no --pool)"
            )

    def starts_later(self, agent: int) -> bool:
        """Whether ``agent``'s process starts later, by :meth:`step`: in lockstep one absent
        at epoch 0 (it joins later); in realtime none, as a start takes seconds that the
        clock does not wait for: it waits for its epoch in the run."""
        return self.period_s is None and not bool(self.team.present[0, agent - 1])

    def step(self, count: int, seen: Callable[[int, int], bool]) -> None:
        """Do what is due: ``count`` epochs are estimated so far; ``seen(i, k)``: ``x_i[k]`` came."""
        elapsed = max(time.monotonic() - self.began, 1e-3)
        rate = count / elapsed if self.period_s is None else 1.0 / self.period_s
        ahead = count + self.lead_s * rate  # the epoch the run reaches in lead_s
        for s in self.steps:
            if s.done:
                continue
            name = f"agent-{s.agent}"
            if s.action == "kill":
                if not seen(s.agent, s.epoch):
                    continue
                self.supervisor.kill_planned(name)
            else:
                earlier = [t for t in self.steps if t.agent == s.agent and t.epoch < s.epoch]
                if any(not t.done for t in earlier) or ahead < s.epoch - 1:
                    continue
                self.supervisor.start_planned(name, "agent", *self.agent_args(s.agent), "--rejoin")
            s.done = True

    def finishing(self, gone: set[str]) -> list[int]:
        """Agents whose final state ``x[E]`` is due: taking part at the end and not lost."""
        return [i for i in self.team.taking_part(self.epochs) if f"agent-{i}" not in gone]


def bodies(
    positions: npt.NDArray[np.float64], x0: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """Where every body is at each epoch, from the states published: an agent out of the team
    stays where its last state put it, one not yet joined where the scenario starts it.

    positions : (E + 1, n, d) published states, NaN where none [m]; x0 : (n, d) initial [m]
    """
    out = positions.copy()
    out[0] = np.where(np.isnan(out[0]), x0, out[0])
    for k in range(1, len(out)):
        out[k] = np.where(np.isnan(out[k]), out[k - 1], out[k])
    return out


__all__ = ["LEAD_S", "EventDriver", "Step", "bodies"]
