"""``python -m netem --scenario F``: the dropping proxy every message crosses."""

from __future__ import annotations

import argparse
import logging
import sys

from formation import zenoh_config
from formation.errors import TestbedError
from formation.scenario import Scenario
from formation.service import Service


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m netem", description=__doc__)
    p.add_argument("--scenario", required=True)
    p.add_argument("--run-id", default="default")
    p.add_argument("--seed", type=int)
    p.add_argument("--epochs", type=int)
    p.add_argument(
        "--passthrough", action="store_true", help="benchmark baseline: forward all, decide nothing"
    )
    p.add_argument(
        "--no-recorder", action="store_true", help="start without waiting for a recorder"
    )
    zenoh_config.add_arguments(p)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    try:
        scenario = Scenario.from_file(args.scenario)
        if args.epochs is not None:
            scenario = scenario.with_overrides(epochs=args.epochs)
    except TestbedError as exc:
        print(f"netem: error: {exc}", file=sys.stderr)
        return 1
    from netem.node import NetemNode

    try:
        service = Service(args.run_id, "netem", 0, args)
    except TestbedError as exc:
        print(f"netem: error: {exc}", file=sys.stderr)
        return 1
    try:
        node = NetemNode(service, scenario, scenario.seed if args.seed is None else args.seed,
                         wait_for_recorder=not args.no_recorder, passthrough=args.passthrough)  # fmt: skip
        service.announce()
        if scenario.runtime.mode == "realtime":
            code = node.run_realtime(
                scenario.runtime.realtime_period_s or scenario.control.period_s
            )
        else:
            code = node.run()
        delivered = node.sent_counts()
        if scenario.runtime.mode == "realtime":  # forwarded on the links' keys, past Service.put
            service.sent.update(delivered)
        service.status("done" if code == 0 else "error", node.estimates_done, delivered=delivered)
        return code
    except TestbedError as exc:
        print(f"netem: error: {exc}", file=sys.stderr)
        return 1
    finally:
        service.close()


if __name__ == "__main__":
    sys.exit(main())
