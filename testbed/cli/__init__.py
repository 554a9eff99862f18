"""The ``formation`` command: one subcommand per job; each prints a clear error and exits 1 on bad input."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from formation.errors import TestbedError
from testbed.cli import deploy, experiment, netem, recorder, run, simulate

_SUBCOMMANDS = (simulate, run, netem, recorder, deploy, experiment)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="formation",
        description="Formation control over packet-dropping links: simulate, run, record, analyse.",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    for module in _SUBCOMMANDS:
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        code: int = args.func(args)
    except TestbedError as exc:
        print(f"formation {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"formation {args.command}: interrupted", file=sys.stderr)
        return 130
    return code


__all__ = ["build_parser", "main"]
