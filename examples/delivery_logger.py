"""A node of your own: it logs what netem delivered to one agent, epoch by epoch.

The smallest node the shell runs (docs/architecture.md "Where to add"): it takes a
``shell.Service`` (so it runs on any bus: Zenoh in a run, ``shell.MemoryBus`` in a test),
writes its epochs once as a loop that takes one phase's inputs per line from its time
policy's phase inbox, and never asks whether the run is lockstep or realtime.

Beside a running run (``formation run``), with the flags every service takes::

    python examples/delivery_logger.py --scenario scenarios/paper.toml --run-id RUN \\
        --mode client --connect tcp/127.0.0.1:7447 --agent 2
"""

from __future__ import annotations

import logging
import sys
from collections import Counter

from formation import keys
from formation.scenario import Scenario
from shell import (
    Loop,
    PhaseInbox,
    Service,
    TimePolicy,
    load_scenario,
    open_service,
    serve,
    service_parser,
    time_policy,
)

log = logging.getLogger("delivery-logger")


class DeliveryLogger:
    """Logs, each epoch, which in-neighbours' states reached agent ``agent``."""

    def __init__(self, service: Service, scenario: Scenario, agent: int) -> None:
        self.service, self.scenario, self.agent = service, scenario, agent
        self.lines: list[str] = []  # one per epoch, as logged
        self.counts: Counter[str] = Counter()  # realtime: in time, late by cause
        service.subscribe(keys.inbox(service.run_id, agent, "state"))
        service.watch_alive()  # netem's liveliness and its start token

    def _epochs(self, inbox: PhaseInbox) -> Loop:
        for k in range(self.scenario.epochs):
            got = yield from inbox.take("state", k)  # one line per phase
            senders = sorted(p.source for p, _state in got[self.agent])
            self.lines.append(f"epoch {k}: agent {self.agent} got states from {senders}")
            log.info("%s", self.lines[-1])

    def run(self, timing: TimePolicy) -> int:
        """Log every epoch of the run under ``timing``; returns an exit code."""
        inbox = timing.inbox(self.service, [self.agent], self.counts)
        if not timing.join(self.service):
            return 1
        loop = self._epochs(inbox)
        return timing.drive(self.service, loop, inbox.route, self.scenario.epochs)


def main(argv: list[str] | None = None) -> int:
    parser = service_parser("delivery_logger", __doc__)
    parser.add_argument("--agent", type=int, default=1, help="the agent whose deliveries to log")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    scenario = load_scenario(args)

    def body(service: Service) -> int:
        return DeliveryLogger(service, scenario, args.agent).run(time_policy(scenario))

    return serve("delivery-logger", lambda: open_service(args, "logger", 0), body)


if __name__ == "__main__":
    sys.exit(main())
