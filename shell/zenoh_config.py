"""Zenoh session configuration from flags and environment; nothing hard-coded to a host."""

from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from formation.errors import RuntimeFailure
from shell.config_files import check_config, check_readable

if TYPE_CHECKING:  # loaded on first use, so a command's --help with these flags stays light
    import zenoh

LEASE_MS = 5000  # a hung process is noticed within ~5 s instead of zenoh's 10 s
# With CongestionControl.BLOCK, zenoh closes a link whose reader stalls this long (default 5 s),
# losing what was queued; lockstep needs every packet, so a loaded machine must not trip it.
BLOCK_BEFORE_CLOSE_US = 60_000_000
# A client started before its router (compose starts services in any order, and podman-compose
# ignores health conditions) retries this long; a wrong endpoint or credentials fail at the end.
CONNECT_TIMEOUT_S = 60.0
RETRY_FIRST_S = 0.1  # first pause between attempts; doubles up to RETRY_MAX_S
RETRY_MAX_S = 1.0
# Zenoh moves every put over 3 KB into a shared-memory pool of 16 MB, allocated on first use,
# and each receiving process maps it on first receipt: page faults for 12 ms at a time on the
# router's and netem's threads in a realtime run's first epochs, when the first large
# messages (the leader's report delivery, decision batches) went out. Ours are kilobytes, and
# copying them costs less: off, 20 agents at 20 Hz (200 epochs, seed 1) missed 0.00-0.04 %
# of their deadlines against 0.10-0.61 % with it on, most in epochs 0-1.
SHARED_MEMORY = "false"

# Who may slow a run down (docs/architecture.md "Back-pressure"). Our publishers BLOCK, and a
# router forwarding a put waits for each receiver's queue: one subscriber attached from outside
# that reads slowly or never would hold the router, and with it every process of the run (seen:
# grid20 stuck at epoch 44, then the publishers' leases expired, not the reader's). So a run's
# sessions know its team, from the file MEMBERS_FILE_ENV names: what goes to a member still
# blocks, what goes to anyone else is dropped when its queue is full, after DROP_WAIT_US.
MEMBER_ENV = "FORMATION_MEMBER"  # this process's name in the team (its Zenoh id follows from it)
MEMBERS_FILE_ENV = "FORMATION_MEMBERS_FILE"  # a JSON list of the team's names (formation run)
MEMBERS_ENV = "FORMATION_MEMBERS"  # or the names, comma-separated (compose.yaml)
DROP_WAIT_US = 10  # zenoh's default 1 ms per put held the router 1 ms per sample for a dead reader


def endpoints(value: str | Sequence[str] | None, env: str) -> list[str]:
    """Endpoints from a flag (comma-separated) or, when absent, the environment variable ``env``."""
    if value is None:
        value = os.environ.get(env, "")
    if isinstance(value, str):
        return [e.strip() for e in value.split(",") if e.strip()]
    return list(value)


def member_zid(name: str) -> str:
    """The Zenoh id of the team member ``name``: the same in every process and every restart."""
    # 16 bytes in hex; zenoh refuses a leading 0, so the first digit is fixed
    return "f" + hashlib.blake2b(name.encode(), digest_size=16).hexdigest()[1:]


def team_qos(members: Iterable[str]) -> list[dict[str, Any]]:
    """Zenoh's ``qos/network`` rules: egress puts drop, except to the members, where they block.

    Each matching rule overwrites the one before, on every transport; ``zids`` is the remote's.
    """
    return [
        {
            "id": "observers",
            "messages": ["put"],
            "flows": ["egress"],
            "overwrite": {"congestion_control": "drop"},
        },
        {
            "id": "team",
            "zids": sorted({member_zid(m) for m in members}),
            "messages": ["put"],
            "flows": ["egress"],
            "overwrite": {"congestion_control": "block"},
        },
    ]


def read_members(path: str | os.PathLike[str]) -> list[str]:
    """The team's names from ``path`` (a JSON list of strings); a clear error otherwise."""
    try:
        names = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise RuntimeFailure(f"{MEMBERS_FILE_ENV} = {str(path)!r}: cannot read it: {exc}") from None
    if not (isinstance(names, list) and names and all(isinstance(n, str) for n in names)):
        raise RuntimeFailure(f"{MEMBERS_FILE_ENV} = {str(path)!r}: expected a JSON list of names")
    return names


def session_config(
    mode: str | None = None,
    connect: str | Sequence[str] | None = None,
    listen: str | Sequence[str] | None = None,
    extra: dict[str, Any] | None = None,
    member: str | None = None,
    members: Sequence[str] | None = None,
) -> zenoh.Config:
    """A config with multicast scouting and shared memory off; ``mode`` from the flag,
    ``ZENOH_MODE`` or ``peer``.

    ``ZENOH_CONFIG`` may name a JSON5 file (e.g. with credentials) loaded first. ``member``
    (else ``FORMATION_MEMBER``) is this session's name in its run's team and ``members``
    (else the file ``FORMATION_MEMBERS_FILE`` names, else ``FORMATION_MEMBERS``) the team:
    only they can slow it down.
    Raises :class:`~formation.errors.UnreadableFile` if this process cannot read the file
    or a file the config names (a certificate, the router's passwords).
    """
    import zenoh

    path = os.environ.get("ZENOH_CONFIG")
    conf = _from_file(path) if path else zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode or os.environ.get("ZENOH_MODE", "peer")))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("transport/shared_memory/enabled", SHARED_MEMORY)
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
    member = member or os.environ.get(MEMBER_ENV)
    if member:
        conf.insert_json5("id", json.dumps(member_zid(member)))
    members_file = os.environ.get(MEMBERS_FILE_ENV)
    if members is None and members_file:
        members = read_members(members_file)
    if members is None:
        members = [m.strip() for m in os.environ.get(MEMBERS_ENV, "").split(",") if m.strip()]
    if members:
        conf.insert_json5("qos/network", json.dumps(team_qos(members)))
        conf.insert_json5(
            "transport/link/tx/queue/congestion_control/drop/wait_before_drop", str(DROP_WAIT_US)
        )
    for key, value in (extra or {}).items():
        conf.insert_json5(key, json.dumps(value))
    check_config(conf)
    return conf


def _from_file(path: str) -> zenoh.Config:
    import zenoh

    check_readable(path, "ZENOH_CONFIG")
    try:
        return zenoh.Config.from_file(path)
    except zenoh.ZError as exc:
        reason = str(exc).split(" at /")[0].strip()
        raise RuntimeFailure(f"{path} (ZENOH_CONFIG): not a Zenoh config: {reason}") from None


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
        "--connect-timeout",
        type=float,
        default=None,
        help="seconds a client retries until its router answers "
        f"(env ZENOH_CONNECT_TIMEOUT_S, default {CONNECT_TIMEOUT_S:g})",
    )
    parser.add_argument(
        "--start-timeout",
        type=float,
        default=120.0,
        help="seconds to wait for the run to start before giving up (default 120)",
    )


def connect_timeout_s(value: float | None = None) -> float:
    """The retry bound: the flag, else ``ZENOH_CONNECT_TIMEOUT_S``, else :data:`CONNECT_TIMEOUT_S`."""
    if value is not None:
        return value
    env = os.environ.get("ZENOH_CONNECT_TIMEOUT_S", "").strip()
    if not env:
        return CONNECT_TIMEOUT_S
    try:
        return float(env)
    except ValueError:
        raise RuntimeFailure(f"ZENOH_CONNECT_TIMEOUT_S = {env!r}; expected seconds") from None


def open_with_retry(
    conf: zenoh.Config,
    where: str,
    timeout_s: float,
    retry: bool = True,
    sleep: Callable[[float], None] = time.sleep,
    clock: Callable[[], float] = time.monotonic,
) -> zenoh.Session:
    """``zenoh.open(conf)``, retried with a growing pause until it succeeds or ``timeout_s`` passes.

    A client whose router is not listening yet fails at once (connection refused); it tries
    again, so services need not start in order. Raises :class:`RuntimeFailure` naming
    ``where`` and the time waited; ``retry=False`` (peers, routers) tries once.
    """
    import zenoh

    deadline = clock() + timeout_s
    pause = RETRY_FIRST_S
    attempts = 0
    while True:
        attempts += 1
        try:
            return zenoh.open(conf)
        except zenoh.ZError as exc:
            reason = str(exc).split(" at /")[0].strip()
            left = deadline - clock()
            if not retry or left <= 0:
                waited = f" within {timeout_s:g} s ({attempts} attempts)" if retry else ""
                raise RuntimeFailure(
                    f"cannot open a Zenoh session ({where}){waited}: {reason}"
                ) from None
        sleep(min(pause, max(left, 0.0)))
        pause = min(pause * 2, RETRY_MAX_S)


def open_session(args: Any) -> zenoh.Session:
    """A session from the service flags; a client retries until its router answers.

    Raises :class:`RuntimeFailure` after ``--connect-timeout`` seconds without a router.
    """
    mode = args.mode or os.environ.get("ZENOH_MODE", "peer")
    where = (
        args.connect or args.listen or os.environ.get("ZENOH_CONNECT") or "the default endpoints"
    )
    return open_with_retry(
        session_config(args.mode, args.connect, args.listen),
        where,
        connect_timeout_s(getattr(args, "connect_timeout", None)),
        retry=mode == "client",
    )
