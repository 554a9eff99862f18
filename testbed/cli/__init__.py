"""The ``formation`` command: one subcommand per job; each prints a clear error and exits 1 on bad input."""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
from collections.abc import Sequence

from testbed.cli.commands import COMMANDS, epilog

# Only argparse and the commands' table load before the arguments are parsed: `formation --help`
# lists the subcommands from the table, and a subcommand imports its own module alone (the
# simulators, Zenoh and the reports take seconds to load on a loaded machine).


def build_parser(command: str | None = None, every: bool = False) -> argparse.ArgumentParser:
    """The parser with ``command``'s subcommands in full (every one's when ``every``); the
    others are listed by name and summary only, without importing their modules."""
    parser = argparse.ArgumentParser(
        prog="formation",
        description="Formation control over packet-dropping links: simulate, run, record, analyse.",
        epilog=epilog(("formation scenarios", "formation simulate paper", "formation run paper"))
        + "\n\n`formation COMMAND --help` shows a command's arguments and examples.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    wanted = {c.module for name, c in COMMANDS.items() if every or name == command}
    for name, cmd in COMMANDS.items():
        if name in sub.choices:  # registered with another command of its module
            continue
        if cmd.module in wanted:
            importlib.import_module(cmd.module).register(sub)
        else:
            sub.add_parser(name, help=cmd.summary)
    for name, cmd in COMMANDS.items():
        if cmd.module in wanted:
            _describe(sub.choices[name], cmd.summary, cmd.examples)
    return parser


def _describe(p: argparse.ArgumentParser, summary: str, examples: tuple[str, ...]) -> None:
    """A subcommand's help: its summary on top, its examples below, laid out as written."""
    p.description = p.description or summary[:1].upper() + summary[1:] + "."
    p.epilog = epilog(examples) + (f"\n\n{p.epilog}" if p.epilog else "")  # then its own notes
    p.formatter_class = argparse.RawDescriptionHelpFormatter


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
    from formation.errors import TestbedError  # here: formation loads numpy and pydantic

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
