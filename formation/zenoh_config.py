"""Zenoh session configuration from flags and environment; nothing hard-coded to a host."""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from typing import Any

import zenoh

LEASE_MS = 5000  # a hung process is noticed within ~5 s instead of zenoh's 10 s
# With CongestionControl.BLOCK, zenoh closes a link whose reader stalls this long (default 5 s),
# losing what was queued; lockstep needs every packet, so a loaded machine must not trip it.
BLOCK_BEFORE_CLOSE_US = 60_000_000


def endpoints(value: str | Sequence[str] | None, env: str) -> list[str]:
    """Endpoints from a flag (comma-separated) or, when absent, the environment variable ``env``."""
    if value is None:
        value = os.environ.get(env, "")
    if isinstance(value, str):
        return [e.strip() for e in value.split(",") if e.strip()]
    return list(value)


def session_config(
    mode: str | None = None,
    connect: str | Sequence[str] | None = None,
    listen: str | Sequence[str] | None = None,
    extra: dict[str, Any] | None = None,
) -> zenoh.Config:
    """A config with multicast scouting off; ``mode`` from the flag, ``ZENOH_MODE`` or ``peer``.

    ``ZENOH_CONFIG`` may name a JSON5 file (e.g. with credentials) loaded first.
    """
    path = os.environ.get("ZENOH_CONFIG")
    conf = zenoh.Config.from_file(path) if path else zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode or os.environ.get("ZENOH_MODE", "peer")))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("transport/link/tx/lease", str(LEASE_MS))
    conf.insert_json5(
        "transport/link/tx/queue/congestion_control/block/wait_before_close",
        str(BLOCK_BEFORE_CLOSE_US),
    )
    conn = endpoints(connect, "ZENOH_CONNECT")
    lst = endpoints(listen, "ZENOH_LISTEN")
    if conn:
        conf.insert_json5("connect/endpoints", json.dumps(conn))
    if lst:
        conf.insert_json5("listen/endpoints", json.dumps(lst))
    for key, value in (extra or {}).items():
        conf.insert_json5(key, json.dumps(value))
    return conf


def add_arguments(parser: Any) -> None:
    """The ``--mode/--connect/--listen`` flags every service takes."""
    parser.add_argument(
        "--mode", choices=["peer", "client", "router"], help="zenoh mode (env ZENOH_MODE)"
    )
    parser.add_argument(
        "--connect", help="endpoints to connect to, comma-separated (env ZENOH_CONNECT)"
    )
    parser.add_argument(
        "--listen", help="endpoints to listen on, comma-separated (env ZENOH_LISTEN)"
    )
    parser.add_argument(
        "--start-timeout",
        type=float,
        default=120.0,
        help="seconds to wait for the run to start before giving up (default 120)",
    )


def open_session(args: Any) -> zenoh.Session:
    return zenoh.open(session_config(args.mode, args.connect, args.listen))
