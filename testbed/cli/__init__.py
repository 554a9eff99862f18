"""The ``formation`` command: one subcommand per job; each prints a clear error and exits 1 on bad input."""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
from collections.abc import Sequence

from formation.errors import TestbedError

# The module that registers each subcommand. Only the one asked for is imported: the
# experiments and reports pull in matplotlib, pandas and the simulators (seconds on a loaded
# machine), which `formation netem set` on a live run should not wait for.
COMMANDS: dict[str, str] = {
    "simulate": "testbed.cli.simulate",
    "run": "testbed.cli.run",
    "netem": "testbed.cli.netem",
    "report": "testbed.cli.recorder",
    "info": "testbed.cli.recorder",
    "recover": "testbed.cli.recorder",
    "export": "testbed.cli.recorder",
    "replay": "testbed.cli.recorder",
    "compose": "testbed.cli.deploy",
    "keys": "testbed.cli.deploy",
    "experiment": "testbed.cli.experiment",
    "sweep": "testbed.cli.experiment",
    "plugins": "testbed.cli.plugins",
    "ros2-plant": "testbed.cli.plant",
    "robots": "testbed.cli.robots",
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser with ``command``'s subcommands, or with every one when ``command`` is None."""
    parser = argparse.ArgumentParser(
        prog="formation",
        description="Formation control over packet-dropping links: simulate, run, record, analyse.",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    chosen = [COMMANDS[command]] if command in COMMANDS else COMMANDS.values()
    for module in dict.fromkeys(chosen):
        importlib.import_module(module).register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    try:
        code = _run(list(sys.argv[1:] if argv is None else argv))
        sys.stdout.flush()  # a closed pipe shows here, not in the interpreter's exit
    except BrokenPipeError:
        _quiet_stdout()
        return 128 + signal.SIGPIPE  # as a Unix tool killed by SIGPIPE: `| head` ends quietly
    return code


def _run(args_in: list[str]) -> int:
    parser = build_parser(args_in[0] if args_in else None)
    try:
        args = parser.parse_args(args_in)
    except SystemExit as exc:  # --help and usage errors: flushed here, so a closed pipe is seen
        sys.stdout.flush()
        return exc.code if isinstance(exc.code, int) else 2
    try:
        code: int = args.func(args)
    except TestbedError as exc:
        print(f"formation {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"formation {args.command}: interrupted", file=sys.stderr)
        return 130
    return code


def _quiet_stdout() -> None:
    """Point stdout at /dev/null, so that nothing more is written to the closed pipe at exit."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


__all__ = ["COMMANDS", "build_parser", "main"]
