"""``python -m testbed.runtime.router --listen tcp/127.0.0.1:7447``: a Zenoh router of our own.

A Zenoh session in ``router`` mode routes between ``client`` sessions; it runs
until SIGINT/SIGTERM. Used by ``formation run`` and by compose. ``ZENOH_CONFIG``
may name a JSON5 file loaded first (access control, TLS, the router's own
credentials, see :mod:`testbed.deploy.security`); ``--passwords`` names the
``user:password`` file clients authenticate against. ``RUST_LOG`` turns on
Zenoh's own log.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading

import zenoh

from formation.errors import TestbedError
from shell import dump_stacks_on_signal, endpoints, session_config


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m testbed.runtime.router", description=__doc__)
    p.add_argument("--listen", help="endpoints, comma-separated (env ZENOH_LISTEN)")
    p.add_argument("--connect", help="other routers to connect to (env ZENOH_CONNECT)")
    p.add_argument("--passwords", help="user:password file; clients must authenticate (usrpwd)")
    args = p.parse_args(argv)
    where = ",".join(endpoints(args.listen, "ZENOH_LISTEN"))
    if not where:
        print(
            "router: error: --listen (or ZENOH_LISTEN) is required, e.g. tcp/127.0.0.1:7447",
            file=sys.stderr,
        )
        return 1
    dump_stacks_on_signal()
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    extra = {"transport/auth/usrpwd/dictionary_file": args.passwords} if args.passwords else None
    zenoh.try_init_log_from_env()
    try:
        session = zenoh.open(session_config("router", args.connect, args.listen, extra))
    except TestbedError as exc:  # a file it cannot read, named with the user and the fix
        print(f"router: error: {exc}", file=sys.stderr)
        return 1
    except zenoh.ZError as exc:
        print(f"router: error: cannot listen on {where}: {exc}", file=sys.stderr)
        return 1
    print(f"router: listening on {where}", flush=True)
    stop.wait()
    session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
