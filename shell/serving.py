"""A service's command line and its life: flags, the scenario, open, signals, run, close, exit code."""

from __future__ import annotations

import argparse
import os
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


def open_service(args: argparse.Namespace, role: str, ident: int | str) -> Service:
    """The service of the command line's run on a Zenoh session of its flags (a client
    retries until its router answers, up to ``--connect-timeout``)."""
    bus = ZenohBus(zenoh_config.open_session(args))
    return Service(bus, args.run_id, role, ident, start_timeout_s=args.start_timeout)


def stop_on_signals(stopping: threading.Event, hard_exit: bool = False) -> None:
    """The first SIGINT or SIGTERM sets ``stopping`` (the service ends cleanly); a second
    exits at once (``hard_exit``: without unwinding, as a file writer wants: every chunk it
    flushed stays readable)."""
    received = 0

    def on_signal(signum: int, frame: FrameType | None) -> None:
        nonlocal received
        received += 1
        stopping.set()
        if received > 1:
            if hard_exit:
                os._exit(128 + signum)
            sys.exit(128 + signum)

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
