"""The agent's one loop on the in-memory bus, in lockstep: each phase waits for netem's
delivery, the report goes out once the states are in, the step once the estimate is in,
and the loop ends after the run's last epoch."""

from __future__ import annotations

import queue
import threading
from pathlib import Path

import orjson

from agent.node import AgentNode
from formation import keys
from formation.messages import Delivery
from formation.scenario import Scenario
from shell import Lockstep, MemoryBus, Sample, Service

ROOT = Path(__file__).resolve().parents[3]
RUN = "agent-loop"


def test_the_lockstep_loop_takes_each_phase_once_its_delivery_is_in() -> None:
    scenario = Scenario.from_file(ROOT / "scenarios/paper.toml").with_overrides(epochs=3)
    bus = MemoryBus()
    netem = Service(bus, RUN, "netem", 0)
    netem.announce()
    svc = Service(bus, RUN, "agent", 1, start_timeout_s=5)
    node = AgentNode(svc, scenario, [1], "estimate", seed=1)
    # netem's side: a delivery answers each state and report, from a thread of its own (the
    # bus delivers on the publishing thread, which holds the agent's lock)
    todo: queue.SimpleQueue[tuple[str, int] | None] = queue.SimpleQueue()
    seen: list[tuple[str, int]] = []

    def on(kind: str):  # type: ignore[no-untyped-def]
        def heard(sample: Sample) -> None:
            epoch = orjson.loads(sample.payload.to_bytes())["epoch"]
            seen.append((kind, epoch))
            if epoch < scenario.epochs:
                todo.put(("state" if kind == "x" else "estimate", epoch))

        return heard

    bus.declare_subscriber(keys.agent_state(RUN, 1), on("x"))
    bus.declare_subscriber(keys.agent_report(RUN, 1), on("report"))

    def netem_side() -> None:
        while (job := todo.get()) is not None:
            phase, epoch = job
            key = keys.inbox(RUN, 1, phase)
            lost = scenario.in_neighbours[0] if phase == "state" else [keys.LEADER_ENDPOINT]
            fields = {**netem.header(key, epoch), "receiver": 1, "phase": phase, "lost": lost}
            netem.publish(key, Delivery(**fields, packets=[]))

    feeder = threading.Thread(target=netem_side)
    feeder.start()
    codes: list[int] = []
    runner = threading.Thread(target=lambda: codes.append(node.run(Lockstep(watch_s=0.01))))
    runner.start()
    netem.declare_start()
    runner.join(10)
    todo.put(None)
    feeder.join(10)
    assert codes == [0] and node.done and node.runner.epoch == scenario.epochs
    assert seen == [(kind, k) for k in range(3) for kind in ("x", "report")] + [("x", 3)]
    assert dict(svc.malformed.counts) == {}
