"""``python -m agent --scenario F --id I`` (or ``--ids 1-50`` for a pooled process)."""

from __future__ import annotations

import json
import logging
import sys
import time

from agent.body import RobotBodies
from agent.node import WATCH_S, AgentNode
from body import exit_process, require_ros2
from formation.errors import PluginFailure, TestbedError
from formation.plugin_api import PLUGIN_EXIT, PLUGIN_FAILED
from shell import Service, load_scenario, open_service, serve, service_parser, time_policy

log = logging.getLogger("agent")


def parse_ids(text: str, n: int) -> list[int]:
    """``"3"``, ``"1-5"`` or ``"1,4,7-9"`` → ids, each checked against the scenario's 1..n."""
    ids: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        try:
            ids.extend(range(int(lo), int(hi or lo) + 1))
        except ValueError:
            raise TestbedError(f"--id {text!r}: expected ids like 3, 1-5 or 1,4,7-9") from None
    for i in ids:
        if not 1 <= i <= n:
            raise TestbedError(f"--id {i}: no such agent in the scenario (agents are 1..{n})")
    return ids


def check_body(kind: str, pose_type: str) -> None:
    """A body this build can drive, with its packages installed; else a clear error."""
    require_ros2(f"body.kind = {kind!r}", pose_type, kind)


def main(argv: list[str] | None = None) -> int:
    p = service_parser("python -m agent", __doc__)
    p.add_argument("--id", "--ids", dest="ids", required=True, help="agent id, or ids for a pool")
    p.add_argument("--strategy", help="a loss strategy plug-in (default: the scenario's)")
    p.add_argument("--seed", type=int)
    p.add_argument(
        "--rejoin",
        action="store_true",
        help="started into a running run (a join, a restart): ask netem from which epoch",
    )
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    try:
        scenario = load_scenario(args)
        ids = parse_ids(args.ids, scenario.n)
        robots = [i for i in ids if scenario.body.has_robot(i)]
        if robots:
            check_body(scenario.body.kind, scenario.body.pose_type)
    except TestbedError as exc:
        print(f"agent: error: {exc}", file=sys.stderr)
        return 1
    role, ident = ("agent", ids[0]) if len(ids) == 1 else ("pool", ids[0])

    def body(service: Service) -> int:
        bodies = None
        if robots:  # rmw_zenoh's body rides on this service's own Zenoh session
            session = getattr(service.bus, "session", None)
            bodies = RobotBodies(scenario, ids, f"formation_{role}_{ident}", session)
        node = AgentNode(
            service,
            scenario,
            ids,
            args.strategy or scenario.strategy.name,
            scenario.seed if args.seed is None else args.seed,
            bodies,
        )
        # Restarted into a running run, or joining it later (a scenario event): ask netem
        # (in lockstep from the epochs it closed, in realtime from the run's clock).
        joins = not scenario.membership.present[0, [i - 1 for i in ids]].all()
        restarted = args.rejoin or joins or service.run_started()
        timing = time_policy(scenario, watch_s=WATCH_S)
        if not restarted:  # a restart's bodies are placed where netem last saw them
            node.place_bodies(timing.realtime)
        node.announce()
        # realtime: a joiner starts with the others and asks once the run has begun
        if restarted and (not timing.realtime or service.wait_started()):
            node.rejoin()
        try:
            code = node.run(timing)
            if service.failure is not None:  # failed in a message handler
                raise service.failure
            counts = node.deadline | ({} if bodies is None else bodies.status_counts())
            detail = json.dumps(counts) if timing.realtime else ""
            if node.body_lost is not None and not timing.realtime:
                detail = str(node.body_lost)  # realtime: the counts, the loss in its log
            service.status("done" if code == 0 else "error", node.runner.epoch, detail)
            if code == 0:
                node.confirm_final()
        except PluginFailure as exc:  # recorded, then the launcher ends the run
            service.status("error", node.runner.epoch, f"{PLUGIN_FAILED}{exc}")
            print(f"agent: error: {exc}", file=sys.stderr, flush=True)
            return PLUGIN_EXIT
        finally:
            cpu_s = time.process_time() - node.cpu_at_start_s
            log.info("cpu: %.3f s over %d epochs", cpu_s, node.runner.epoch)
            if bodies is not None:  # the robots stop: the run's end, a signal or a loss
                bodies.stop()
                log.info("body: %s", json.dumps(bodies.summary()))
                bodies.close()
        return code

    return serve("agent", lambda: open_service(args, role, ident), body)


if __name__ == "__main__":
    exit_process(main())  # past rclpy's teardown, if a body used it
