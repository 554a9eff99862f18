"""A subscriber process for the benches: counts samples on a key, then prints JSON and exits.

``python -m bench.count_subscriber ENDPOINT KEY EXPECTED TIMEOUT_S [deliveries]`` prints
``{"count": N, "first_ns": t0, "last_ns": t1}`` (``time.time_ns()``, shared by
processes on one machine) once ``EXPECTED`` samples arrived or the time is up.
With ``deliveries``, each sample is a lockstep ``Delivery`` and counts its packets' copies.
It prints ``ready`` first, once its subscriber is declared.
"""

from __future__ import annotations

import json
import sys
import threading
import time

import orjson
import zenoh

from shell import session_config


def main(argv: list[str]) -> int:
    endpoint, key, expected, timeout_s = argv[0], argv[1], int(argv[2]), float(argv[3])
    deliveries = argv[4:] == ["deliveries"]
    got = {"count": 0, "first_ns": 0, "last_ns": 0}
    done = threading.Event()

    def count(sample: zenoh.Sample) -> None:
        t = time.time_ns()
        got["first_ns"] = got["first_ns"] or t
        got["last_ns"] = t
        if deliveries:
            packets = orjson.loads(sample.payload.to_bytes())["packets"]
            got["count"] += sum(p["copies"] for p in packets)
        else:
            got["count"] += 1
        if got["count"] >= expected:
            done.set()

    with zenoh.open(session_config("peer", endpoint, "tcp/127.0.0.1:0")) as session:
        sub = session.declare_subscriber(key, count)
        print("ready", flush=True)
        done.wait(timeout_s)
        sub.undeclare()
    print(json.dumps(got), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
