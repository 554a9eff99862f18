"""``python -m leader --scenario F``: the leader / reference estimator process."""

from __future__ import annotations

import json
import logging
import sys

from leader.node import LeaderNode
from shell import (
    Service,
    open_service,
    scenario_or_report,
    serve,
    service_parser,
    time_policy,
)


def main(argv: list[str] | None = None) -> int:
    args = service_parser("python -m leader", __doc__).parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    scenario = scenario_or_report("leader", args)
    if scenario is None:
        return 1

    def body(service: Service) -> int:
        node = LeaderNode(service, scenario)
        restarted = scenario.runtime.mode == "lockstep" and service.run_started()
        service.announce()
        if restarted:
            node.rejoin()
        timing = time_policy(scenario, watch_s=0.05)
        code = node.run(timing)
        realtime = timing.realtime
        service.status(
            "done" if code == 0 else "error",
            node.epoch,
            json.dumps(node.deadline) if realtime else "",
        )
        if code == 0:
            node.confirm_last()
        return code

    return serve("leader", lambda: open_service(args, "leader", 0), body)


if __name__ == "__main__":
    sys.exit(main())
