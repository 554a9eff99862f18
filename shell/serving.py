"""A service's command line and its life: flags, the scenario, open, run, close, exit code."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable

from formation.errors import TestbedError
from formation.scenario import Scenario
from shell import zenoh_config
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


def serve(name: str, open_service: Callable[[], Service], body: Callable[[Service], int]) -> int:
    """Open the service, run ``body`` and close it; a :class:`TestbedError` is printed as
    ``name: error: …`` with exit code 1."""
    dump_stacks_on_signal()
    try:
        service = open_service()
    except TestbedError as exc:
        print(f"{name}: error: {exc}", file=sys.stderr)
        return 1
    try:
        return body(service)
    except TestbedError as exc:
        print(f"{name}: error: {exc}", file=sys.stderr)
        return 1
    finally:
        service.close()
