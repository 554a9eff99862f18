"""``python -m testbed.router --listen tcp/127.0.0.1:7447``: a Zenoh router of our own.

A Zenoh session in ``router`` mode routes between ``client`` sessions; it runs
until SIGINT/SIGTERM. Used by ``formation run`` and by compose.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading

import zenoh

from formation import zenoh_config


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m testbed.router", description=__doc__)
    p.add_argument("--listen", help="endpoints, comma-separated (env ZENOH_LISTEN)")
    p.add_argument("--connect", help="other routers to connect to (env ZENOH_CONNECT)")
    args = p.parse_args(argv)
    if not zenoh_config.endpoints(args.listen, "ZENOH_LISTEN"):
        print("router: error: --listen (or ZENOH_LISTEN) is required, e.g. tcp/127.0.0.1:7447", file=sys.stderr)
        return 1
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    try:
        session = zenoh.open(zenoh_config.session_config("router", args.connect, args.listen))
    except zenoh.ZError as exc:
        print(f"router: error: cannot listen on {args.listen}: {exc}", file=sys.stderr)
        return 1
    print(f"router: listening on {args.listen}", flush=True)
    stop.wait()
    session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
