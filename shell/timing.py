"""When a node's one loop takes its inputs: the time policy (docs/architecture.md "Time").

A node writes its epochs once, as a generator (a :data:`Loop`) that yields a :class:`Wait`
before each phase takes its inputs; a :class:`TimePolicy` drives it:

- :class:`Lockstep`: a phase ends once its inputs are in (netem's delivery closes it). The
  loop advances on the bus's receiving thread as each input is routed, with no hand-off
  to another thread; the main thread only watches netem's liveliness and the signals.
- :class:`Realtime`: a phase ends at its deadline in the run's clock (or sooner, once
  nothing more can come), and the loop runs on the main thread
  (:meth:`~shell.service.Service.take_by`).

A node's inputs wait in the policy's :meth:`TimePolicy.inbox` (:mod:`shell.inbox`), so no
node tests the mode. netem owns the clock: it starts the run with :meth:`TimePolicy.begin`;
the others join it with :meth:`TimePolicy.join`.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable, MutableMapping
from typing import Protocol

from formation.errors import TestbedError
from formation.realtime import Clock, sleep_until
from formation.scenario import Scenario
from shell.clock import fetch_clock
from shell.inbox import LockstepInbox, PhaseInbox, RealtimeInbox
from shell.loop import Loop, Route, Wait
from shell.service import Incoming, Service, drain_last

log = logging.getLogger("service")


class TimePolicy(Protocol):
    """Lockstep or realtime: how a node's one loop meets time."""

    @property
    def realtime(self) -> bool:
        """Whether phases end at deadlines of a wall clock."""
        ...

    @property
    def clock(self) -> Clock | None:
        """The run's clock once started (realtime), else None."""
        ...

    def begin(self, service: Service, lead_s: float = 0.0) -> None:
        """netem: start the run (realtime: its clock starts ``lead_s`` from now)."""
        ...

    def join(self, service: Service, rehearse: Callable[[], None] | None = None) -> bool:
        """Wait for netem's start (realtime: and fetch the clock); False if stopped first.

        ``rehearse``: realtime, a node's own work of an epoch on copies, done before the
        clock starts. A first run costs several times the later ones (CPython specialises
        code as it runs it), and every process would pay it at the same first deadline.
        """
        ...

    def inbox(
        self, service: Service, receivers: Iterable[int], counts: MutableMapping[str, int]
    ) -> PhaseInbox:
        """The phase inbox of a node's ``receivers`` in this mode (:mod:`shell.inbox`);
        realtime counts its deadlines' outcomes in ``counts``."""
        ...

    def past(self, epoch: int, at: float) -> bool:
        """Whether epoch ``epoch``'s deadline at ``at`` has passed already (lockstep: never)."""
        ...

    def sleep_until(self, epoch: int, at: float) -> None:
        """Sleep until epoch ``epoch``'s deadline at ``at`` (lockstep: return at once)."""
        ...

    def drive(self, service: Service, loop: Loop, route: Route, end: int) -> int:
        """Run ``loop`` to its end, ``route`` filing every input; returns an exit code:
        0 done, 130 stopped, 2 netem gone, 1 the loop failed (lockstep). ``end``: the run's epochs (realtime:
        inputs still come until netem has gone after ``clock.at(end)``)."""
        ...


class Lockstep:
    """Lockstep: no clock; a phase ends once its inputs are in.

    ``watch_s``: how often the main thread looks for netem's liveliness and a signal.
    """

    realtime = False
    clock: Clock | None = None

    def __init__(self, watch_s: float = 0.25) -> None:
        self.watch_s = watch_s

    def __repr__(self) -> str:
        return f"Lockstep(watch_s={self.watch_s:g})"

    def begin(self, service: Service, lead_s: float = 0.0) -> None:
        service.declare_start()

    def join(self, service: Service, rehearse: Callable[[], None] | None = None) -> bool:
        return service.wait_started()

    def inbox(
        self, service: Service, receivers: Iterable[int], counts: MutableMapping[str, int]
    ) -> PhaseInbox:
        return LockstepInbox(service, receivers, counts)

    def past(self, epoch: int, at: float) -> bool:
        return False

    def sleep_until(self, epoch: int, at: float) -> None:
        pass

    def drive(self, service: Service, loop: Loop, route: Route, end: int) -> int:
        """Inputs are routed as they arrive, on the bus's thread, and each routed input
        advances the loop as far as its waits are complete; this thread only watches."""
        done = threading.Event()
        failed: list[BaseException] = []  # the loop raised: it cannot go on
        waiting: list[Wait] = []  # the loop's current wait; empty before its start

        def advance() -> None:
            try:
                while not waiting or _complete(waiting[0]):
                    waiting[:] = [loop.send(False) if waiting else next(loop)]
            except StopIteration:
                done.set()
            except BaseException as exc:
                failed.append(exc)
                done.set()
                raise

        def on_message(msg: Incoming) -> None:
            route(msg)
            if not done.is_set():
                advance()

        with service.inline_lock:
            service.inline = on_message
            while (early := service.next_incoming(0)) is not None:
                route(early)
            advance()
        # A slow watch: 50 agent processes waking 20 times a second cost 2 % of the machine.
        while not done.wait(self.watch_s) and not service.stopping.is_set():
            if service.gone_for("netem", 0):
                log.error("netem is gone; stopping")
                return 2
        if failed:
            if isinstance(failed[0], TestbedError):  # a reason for the user: the node says it
                raise failed[0]
            log.error("the epoch loop failed: %r", failed[0])
            return 1
        return 0 if done.is_set() else 130


def _complete(wait: Wait) -> bool:
    if wait.complete is None:
        raise ValueError(f"a lockstep wait needs its inputs' completion (epoch {wait.epoch})")
    return wait.complete()


class Realtime:
    """Realtime: a fixed period ``period_s`` [s]; what has not arrived by a phase's deadline
    is lost."""

    realtime = True

    def __init__(self, period_s: float) -> None:
        if not period_s > 0:
            raise ValueError(f"Realtime(period_s={period_s!r}); expected > 0")
        self.period_s = period_s
        self.clock: Clock | None = None

    def __repr__(self) -> str:
        return f"Realtime(period_s={self.period_s:g})"

    def _started(self) -> Clock:
        if self.clock is None:
            raise RuntimeError("the realtime clock is not started (begin or join first)")
        return self.clock

    def begin(self, service: Service, lead_s: float = 0.0) -> None:
        self.clock = Clock(time.time_ns() + int(lead_s * 1e9), int(self.period_s * 1e9))
        service.declare_start()

    def join(self, service: Service, rehearse: Callable[[], None] | None = None) -> bool:
        if rehearse is not None:
            rehearse()  # while the others start: the clock is not running yet
        if not service.wait_started():
            return False
        self.clock = fetch_clock(service.bus, service.run_id)
        return True

    def inbox(
        self, service: Service, receivers: Iterable[int], counts: MutableMapping[str, int]
    ) -> PhaseInbox:
        return RealtimeInbox(service, receivers, counts, lambda: self.clock)

    def past(self, epoch: int, at: float) -> bool:
        return time.time_ns() > self._started().at(epoch, at)

    def sleep_until(self, epoch: int, at: float) -> None:
        sleep_until(self._started().at(epoch, at))

    def drive(self, service: Service, loop: Loop, route: Route, end: int) -> int:
        """Each wait is one :meth:`~shell.service.Service.take_by` on this thread; after the
        last, late inputs are routed (and counted) until netem has gone."""
        clock = self._started()
        held: list[Incoming] = []
        wait: Wait | None = next(loop, None)
        while wait is not None:
            due = clock.at(wait.epoch, wait.at)
            held = service.take_by(due, route, held, wait.complete)
            if service.stopping.is_set():
                return 130
            try:
                wait = loop.send(time.time_ns() < due)
            except StopIteration:
                wait = None
        held = service.take_by(clock.at(end), route, held)
        if service.stopping.is_set():
            return 130
        for queued in held:
            route(queued)
        drain_last(service, route)
        return 0


def time_policy(scenario: Scenario, watch_s: float = 0.25) -> TimePolicy:
    """The scenario's time: :class:`Realtime` at its period (``runtime.realtime_period_s``,
    else ``control.period_s``), else :class:`Lockstep` watching every ``watch_s``."""
    runtime = scenario.runtime
    if runtime.mode == "realtime":
        return Realtime(runtime.realtime_period_s or scenario.control.period_s)
    return Lockstep(watch_s)
