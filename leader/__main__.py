"""``python -m leader --scenario F``: the leader / reference estimator process."""

from __future__ import annotations

import argparse
import logging
import sys

from formation import zenoh_config
from formation.errors import TestbedError
from formation.scenario import Scenario
from formation.service import Service


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m leader", description=__doc__)
    p.add_argument("--scenario", required=True)
    p.add_argument("--run-id", default="default")
    p.add_argument("--epochs", type=int)
    zenoh_config.add_arguments(p)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    try:
        scenario = Scenario.from_file(args.scenario)
        if args.epochs is not None:
            scenario = scenario.with_overrides(epochs=args.epochs)
    except TestbedError as exc:
        print(f"leader: error: {exc}", file=sys.stderr)
        return 1
    from leader.node import LeaderNode

    try:
        service = Service(args.run_id, "leader", 0, args)
    except TestbedError as exc:
        print(f"leader: error: {exc}", file=sys.stderr)
        return 1
    try:
        node = LeaderNode(service, scenario)
        restarted = scenario.runtime.mode == "lockstep" and service.run_started()
        service.announce()
        if restarted:
            node.rejoin()
        code = node.run_realtime() if scenario.runtime.mode == "realtime" else node.run()
        service.status("done" if code == 0 else "error", node.epoch)
        if code == 0:
            node.confirm_last()
        return code
    except TestbedError as exc:
        print(f"leader: error: {exc}", file=sys.stderr)
        return 1
    finally:
        service.close()


if __name__ == "__main__":
    sys.exit(main())
