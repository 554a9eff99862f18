"""A service's command line and its life: flags, the scenario, open, signals, run, close, exit code."""

from __future__ import annotations

import argparse
import contextlib
import os
import queue
import signal
import sys
import threading
from collections.abc import Callable
from types import FrameType

from formation.errors import TestbedError
from formation.scenario import Scenario
from shell import zenoh_config
from shell.bus import ZenohBus
from shell.service import Service
from shell.stack_dump import dump_stacks_on_signal


def service_parser(prog: str, description: str | None) -> argparse.ArgumentParser:
    """A service's command line: ``--scenario``, ``--run-id``, ``--epochs`` and Zenoh's flags."""
    p = argparse.ArgumentParser(prog=prog, description=description)
    p.add_argument("--scenario", required=True)
    p.add_argument("--run-id", default="default")
    p.add_argument("--epochs", type=int, help="overrides the scenario's epochs")
    zenoh_config.add_arguments(p)
    return p


def load_scenario(args: argparse.Namespace) -> Scenario:
    """The scenario of ``--scenario``, with ``--epochs`` applied."""
    scenario = Scenario.from_file(args.scenario)
    return scenario if args.epochs is None else scenario.with_overrides(epochs=args.epochs)


def scenario_or_report(role: str, args: argparse.Namespace) -> Scenario | None:
    """:func:`load_scenario`, or None after one line on stderr (``role: error: …``): a service
    that cannot read its scenario exits 1 before it opens a session."""
    try:
        return load_scenario(args)
    except TestbedError as exc:
        print(f"{role}: error: {exc}", file=sys.stderr)
        return None


def open_service(args: argparse.Namespace, role: str, ident: int | str) -> Service:
    """The service of the command line's run on a Zenoh session of its flags (a client
    retries until its router answers, up to ``--connect-timeout``)."""
    bus = ZenohBus(zenoh_config.open_session(args))
    return Service(bus, args.run_id, role, ident, start_timeout_s=args.start_timeout)


SET_WAIT_S = 0.5  # [s] the longest a signal handler waits for ``stopping`` to be set


def stop_on_signals(stopping: threading.Event, hard_exit: bool = False) -> None:
    """The first SIGINT or SIGTERM sets ``stopping`` (the service ends cleanly); a second
    exits at once (``hard_exit``: without unwinding, as a file writer wants: every chunk it
    flushed stays readable).

    A Python handler runs on the main thread between two bytecodes, maybe while that thread
    holds ``stopping``'s lock (inside ``Event.wait``): calling ``stopping.set()`` there would
    wait for ever. So the handler takes no lock the interrupted code may hold: it puts the
    signal on a queue (``SimpleQueue.put`` is reentrant) and a thread started here sets
    ``stopping``. The handler waits up to ``SET_WAIT_S`` for it, so that the interrupted code
    finds ``stopping`` set, unless it held that lock: then it is set once the lock is free.
    """
    received = 0
    signals: queue.SimpleQueue[int] = queue.SimpleQueue()
    done: queue.SimpleQueue[bool] = queue.SimpleQueue()

    def set_stopping() -> None:
        signals.get()
        stopping.set()
        done.put(True)

    def on_signal(signum: int, frame: FrameType | None) -> None:
        nonlocal received
        received += 1
        if received > 1:
            if hard_exit:
                os._exit(128 + signum)
            sys.exit(128 + signum)
        signals.put(signum)
        # Empty: the interrupted code holds stopping's lock; it is set once it lets go
        with contextlib.suppress(queue.Empty):
            done.get(timeout=SET_WAIT_S)

    threading.Thread(target=set_stopping, name="stop-on-signals", daemon=True).start()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, on_signal)


def serve(
    name: str,
    open_service: Callable[[], Service],
    body: Callable[[Service], int],
    hard_exit: bool = False,
) -> int:
    """Open the service, take the signals, run ``body`` and close it; a :class:`TestbedError`
    is printed as ``name: error: …`` with exit code 1. ``hard_exit``: see
    :func:`stop_on_signals`."""
    dump_stacks_on_signal()
    try:
        service = open_service()
    except TestbedError as exc:
        print(f"{name}: error: {exc}", file=sys.stderr)
        return 1
    stop_on_signals(service.stopping, hard_exit)
    try:
        return body(service)
    except TestbedError as exc:
        print(f"{name}: error: {exc}", file=sys.stderr)
        return 1
    finally:
        service.close()
