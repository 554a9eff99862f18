"""``formation replay``: a recording published back onto Zenoh with its timing (or to Foxglove).

Its flags include the shell's Zenoh flags (:func:`shell.add_arguments`), which
load no Zenoh until a session opens, so its ``--help`` stays light.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from shell import add_arguments


def cmd_replay(args: argparse.Namespace) -> int:
    from recorder import replay

    return replay(args)


def register(sub: Any) -> None:
    """Add ``replay`` to the ``formation`` subparsers."""
    p = sub.add_parser("replay", help="publish a recording back onto Zenoh with its timing")
    p.add_argument("recording", type=Path, help="a run.mcap file")
    p.add_argument("--rate", type=float, default=1.0, help="speed factor (2 = twice as fast)")
    p.add_argument("--loop", action="store_true", help="start again at the end")
    p.add_argument(
        "--start", type=float, default=0.0, help="seconds into the recording to start at"
    )
    p.add_argument("--topics", help="key expressions to replay, comma-separated (default: all)")
    p.add_argument("--prefix", help="publish under this prefix instead of formation/<run_id>")
    p.add_argument(
        "--paused", action="store_true", help="wait for a resume command before publishing"
    )
    p.add_argument(
        "--foxglove",
        type=int,
        metavar="PORT",
        help="serve it to Foxglove on ws://127.0.0.1:PORT instead of Zenoh",
    )
    add_arguments(p)
    p.set_defaults(func=cmd_replay)


__all__ = ["register"]
