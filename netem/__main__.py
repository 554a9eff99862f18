"""``python -m netem --scenario F``: the dropping proxy every message crosses."""

from __future__ import annotations

import json
import logging
import sys

from formation.errors import PluginFailure
from formation.plugin_api import PLUGIN_EXIT, PLUGIN_FAILED
from netem.node import NetemNode
from shell import (
    Service,
    open_service,
    scenario_or_report,
    serve,
    service_parser,
    time_policy,
)


def main(argv: list[str] | None = None) -> int:
    p = service_parser("python -m netem", __doc__)
    p.add_argument("--seed", type=int)
    p.add_argument(
        "--passthrough", action="store_true", help="benchmark baseline: forward all, decide nothing"
    )
    p.add_argument(
        "--no-recorder", action="store_true", help="start without waiting for a recorder"
    )
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    scenario = scenario_or_report("netem", args)
    if scenario is None:
        return 1

    def body(service: Service) -> int:
        node = NetemNode(
            service,
            scenario,
            scenario.seed if args.seed is None else args.seed,
            wait_for_recorder=not args.no_recorder,
            passthrough=args.passthrough,
        )
        service.announce()
        timing = time_policy(scenario)
        try:
            code = node.run(timing)
            if service.failure is not None:  # failed in a message handler
                raise service.failure
        except PluginFailure as exc:  # recorded, then the launcher ends the run
            service.status("error", node.estimates_done, f"{PLUGIN_FAILED}{exc}")
            print(f"netem: error: {exc}", file=sys.stderr, flush=True)
            return PLUGIN_EXIT
        delivered = node.sent_counts()
        detail = json.dumps(node.realtime.deadline) if timing.realtime else ""
        service.status("done" if code == 0 else "error", node.estimates_done, detail, delivered)
        return code

    return serve("netem", lambda: open_service(args, "netem", 0), body)


if __name__ == "__main__":
    sys.exit(main())
