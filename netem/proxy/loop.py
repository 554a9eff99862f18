"""netem's one loop, in lockstep or realtime (docs/architecture.md "Time").

The loop is the same in both: wait for a packet as long as the mode's :class:`Wakeups`
says, look for dead senders, hand the packet over. What a wake-up does is the mode's:
lockstep flushes closed epochs' records (packets are handled on the bus's thread,
:class:`netem.node.LockstepWakeups`); realtime forwards what is due, flushes the
receivers' deliveries and publishes the records once a period
(:class:`netem.proxy.realtime.RealtimeForwarder`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

from shell import Incoming, Service, TimePolicy


class Wakeups(Protocol):
    """What netem does at each wake-up of its loop, in lockstep or realtime."""

    def open(self) -> None:
        """Before everyone is up."""
        ...

    def begin(self, timing: TimePolicy) -> None:
        """Start the run (``timing.begin``)."""
        ...

    def idle(self) -> bool:
        """Whether nothing is held to forward later."""
        ...

    def tick(self) -> float:
        """Before a wait: what is due now; returns how long to wait for a packet [s]."""
        ...

    def wake(self, msg: Incoming | None) -> None:
        """After a wait: the packet that came (None: the wait timed out)."""
        ...

    def end(self) -> None:
        """After the loop, also when it fails."""
        ...


def run_loop(
    service: Service,
    timing: TimePolicy,
    wakeups: Wakeups,
    ready: Callable[[], bool],
    check_dead: Callable[[], None],
    finished: Callable[[], bool],
) -> int:
    """netem's one loop: once ``ready`` (everyone is up), start the run; then wait for a
    packet (as long as ``wakeups.tick`` says), look for dead senders, hand the packet to
    ``wakeups``; until ``finished`` and idle (0), or stopped (130)."""
    wakeups.open()
    while not ready():
        if service.stopping.wait(0.02):
            return 130
    wakeups.begin(timing)
    try:
        while not (finished() and wakeups.idle()) and not service.stopping.is_set():
            msg = service.next_incoming(wakeups.tick())
            check_dead()
            wakeups.wake(msg)
    finally:
        wakeups.end()
    return 0 if finished() else 130
