"""netem process: forwarded coordination packets per second, deciding and recording, vs pass-through.

Baseline: the same netem process with ``--passthrough`` (forwards every packet,
decides and records nothing), in the same run. One sender (agent 1 of the paper
scenario, 3 out-links) publishes as fast as it can; a subscriber counts what netem
delivers on ``link/1/*/state``. Seed: the scenario's (1); no loss configured.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time

import zenoh

from bench.netem_rig import RUN, netem_rig
from formation import keys
from formation.codec import attachment, encode, now_ns
from formation.messages import CoordinationState

PACKETS = 40_000
OUT_LINKS = 3  # agent 1 → 2, 3, 4


def forward_rate(passthrough: bool) -> tuple[float, float]:
    """(forwarded packets/s as a separate subscriber process sees them, sent packets/s)."""
    expected = PACKETS * OUT_LINKS
    with netem_rig(epochs=PACKETS + 10, passthrough=passthrough) as (session, endpoint):
        counter = subprocess.Popen(
            [sys.executable, "-m", "bench.count_subscriber", endpoint, f"{keys.prefix(RUN)}/link/1/*/state",
             str(expected), "60"],
            stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        try:
            assert counter.stdout is not None
            if counter.stdout.readline().strip() != "ready":
                raise RuntimeError("the counting subscriber did not start")
            pub = session.declare_publisher(
                keys.agent_state(RUN, 1), congestion_control=zenoh.CongestionControl.BLOCK
            )
            time.sleep(0.5)  # the counter's subscription travels to netem through gossip
            payloads = [
                encode(
                    CoordinationState(
                        run_id=RUN,
                        sender="agent/1",
                        seq=k,
                        epoch=k,
                        stamp_ns=now_ns(),
                        agent=1,
                        position=[0.1 * k, 0.2],
                    )
                )
                for k in range(PACKETS)
            ]
            start = time.time_ns()
            for k, payload in enumerate(payloads):
                pub.put(payload, attachment=attachment(k, k, 1))
            sent_s = (time.time_ns() - start) / 1e9
            result = json.loads(counter.communicate(timeout=90)[0].strip().splitlines()[-1])
            pub.undeclare()
        finally:
            if counter.poll() is None:
                counter.kill()
                counter.wait()
    if result["count"] < expected:
        print(f"  warning: {result['count']} of {expected} forwarded packets seen")
    return result["count"] / ((result["last_ns"] - start) / 1e9), PACKETS / sent_s


def main() -> None:
    print(
        f"{PACKETS} packets from one sender with {OUT_LINKS} out-links; baseline: netem --passthrough"
    )
    base, base_sent = forward_rate(passthrough=True)
    rate, sent = forward_rate(passthrough=False)
    print(f"pass-through      {base:10.0f} forwarded/s (sender offered {base_sent:.0f} packets/s)")
    print(f"lockstep netem    {rate:10.0f} forwarded/s (sender offered {sent:.0f} packets/s)")
    cost = 100 * (base / rate - 1)
    print(
        f"ratio netem / pass-through {rate / base:.2f} (the loss logic costs {cost:.0f}% more per packet)"
    )


if __name__ == "__main__":
    main()
