"""The time policies drive a node's one loop: lockstep on the bus's thread as inputs come,
realtime at deadlines of the run's clock (on the in-memory bus)."""

from __future__ import annotations

import signal
import threading
import time

import pytest

from formation import keys
from formation.realtime import Clock
from formation.scenario import Scenario
from shell import (
    Incoming,
    Lockstep,
    Loop,
    MemoryBus,
    Realtime,
    Service,
    time_policy,
)
from shell.loop import Wait
from shell.serving import stop_on_signals

RUN = "timing"
KEY = keys.inbox(RUN, 1, "state")


def _services() -> tuple[MemoryBus, Service, Service]:
    bus = MemoryBus()
    netem = Service(bus, RUN, "netem", 0)
    node = Service(bus, RUN, "agent", 1, start_timeout_s=1.0)
    node.subscribe(KEY)
    node.watch_alive()
    netem.announce()
    return bus, netem, node


def test_lockstep_advances_the_loop_as_each_phase_input_is_routed() -> None:
    _, netem, node = _services()
    got: list[bytes] = []
    trace: list[tuple[str, int, bool]] = []

    def loop() -> Loop:
        for k in range(3):
            early = yield Wait(k, 0.2, lambda k=k: len(got) > k)  # type: ignore[misc]
            trace.append(("took", k, early))

    netem.put(KEY, b"0")  # before the start: queued, routed first
    feeder = threading.Timer(0.05, lambda: (netem.put(KEY, b"1"), netem.put(KEY, b"2")))
    feeder.start()
    code = Lockstep(watch_s=0.01).drive(node, loop(), lambda m: got.append(m.payload), end=3)
    feeder.join()
    assert code == 0
    assert got == [b"0", b"1", b"2"]
    assert trace == [("took", 0, False), ("took", 1, False), ("took", 2, False)]
    assert node.inline is not None  # later inputs are handled on the bus's thread


def test_lockstep_stops_on_a_stop_and_when_netem_is_gone() -> None:
    _, netem, node = _services()

    def never() -> Loop:
        yield Wait(0, 0.2, lambda: False)

    node.stopping.set()
    assert Lockstep(watch_s=0.01).drive(node, never(), lambda m: None, end=1) == 130
    node.stopping.clear()
    netem.close()  # its token goes
    assert not node.is_alive("netem", 0)
    node.gone_for("netem", 0, grace_s=0.0)
    node._missing_since[("netem", "0")] -= 10**10  # gone long enough already
    assert Lockstep(watch_s=0.01).drive(node, never(), lambda m: None, end=1) == 2


def test_a_lockstep_wait_needs_its_completion() -> None:
    _, _, node = _services()

    def open_ended() -> Loop:
        yield Wait(0, 0.2)

    with pytest.raises(ValueError, match="a lockstep wait needs its inputs' completion"):
        Lockstep().drive(node, open_ended(), lambda m: None, end=1)


def test_realtime_takes_each_phase_by_its_deadline_or_once_complete() -> None:
    _, netem, node = _services()
    timing = Realtime(period_s=0.1)
    assert repr(timing) == "Realtime(period_s=0.1)"
    netem.queryable(keys.clock(RUN), lambda q: q.reply(q.key_expr, clock.to_json()))
    clock = Clock(time.time_ns() + 300_000_000, 100_000_000)  # room for a loaded machine to join
    netem.declare_start()
    assert timing.join(node) and timing.clock == clock
    routed: list[Incoming] = []
    trace: list[tuple[int, bool]] = []

    def loop() -> Loop:
        trace.append((0, (yield Wait(0, 0.2))))  # until the deadline: not early
        netem.put(KEY, b"in")
        trace.append((0, (yield Wait(0, 0.85, lambda: len(routed) == 1))))  # at once: early
        netem.close()  # its last forwards are in: the drain ends

    assert not timing.past(0, 0.2)
    assert timing.drive(node, loop(), routed.append, end=1) == 0
    assert trace == [(0, False), (0, True)]
    assert [m.payload for m in routed] == [b"in"]
    assert time.time_ns() >= clock.at(1)  # it waited for the end of the run's last epoch
    assert timing.past(0, 0.2)


def test_the_scenarios_time_and_its_checks(paper: Scenario) -> None:
    assert repr(time_policy(paper, watch_s=0.05)) == "Lockstep(watch_s=0.05)"
    realtime = paper.with_overrides(runtime={"mode": "realtime", "realtime_period_s": 0.05})
    assert repr(time_policy(realtime)) == "Realtime(period_s=0.05)"
    with pytest.raises(ValueError, match=r"Realtime\(period_s=0\); expected > 0"):
        Realtime(0)
    with pytest.raises(RuntimeError, match="the realtime clock is not started"):
        Realtime(1.0).past(0, 0.2)


def test_a_first_signal_stops_a_second_exits() -> None:
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    stopping = threading.Event()
    try:
        stop_on_signals(stopping)
        signal.raise_signal(signal.SIGTERM)
        assert stopping.is_set()
        with pytest.raises(SystemExit) as exited:
            signal.raise_signal(signal.SIGINT)
        assert exited.value.code == 128 + signal.SIGINT
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
