"""The newcomer's example node (examples/delivery_logger.py) on the in-memory bus: it logs
each epoch's delivery once netem's delivery of it is in, and ends after the run's last
epoch."""

from __future__ import annotations

import importlib.util
import threading
from pathlib import Path
from types import ModuleType

from formation import keys
from formation.messages import CoordinationState, DeliveredPacket, Delivery
from formation.scenario import Scenario
from shell import Lockstep, MemoryBus, Service

ROOT = Path(__file__).resolve().parents[3]
RUN = "example-node"


def _example() -> ModuleType:
    spec = importlib.util.spec_from_file_location(
        "delivery_logger", ROOT / "examples/delivery_logger.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _state(netem: Service, source: int, epoch: int) -> DeliveredPacket:
    state = CoordinationState(**netem.header(keys.agent_state(RUN, source), epoch), agent=source,
                              position=[float(source), 0.0])  # fmt: skip
    return DeliveredPacket(
        source=source, seq=epoch, sent_epoch=epoch, message=state.model_dump_json()
    )


def test_the_example_logs_each_epochs_delivery_in_lockstep() -> None:
    scenario = Scenario.from_file(ROOT / "scenarios/paper.toml").with_overrides(epochs=3)
    bus = MemoryBus()
    netem = Service(bus, RUN, "netem", 0)
    netem.announce()
    svc = Service(bus, RUN, "logger", 0, start_timeout_s=5)
    logger = _example().DeliveryLogger(svc, scenario, agent=2)
    key = keys.inbox(RUN, 2, "state")

    def deliver(epoch: int, sources: list[int]) -> None:
        packets = [_state(netem, j, epoch) for j in sources]
        msg = Delivery(**netem.header(key, epoch), receiver=2, phase="state", packets=packets,
                       lost=[j for j in (1, 3) if j not in sources])  # fmt: skip
        netem.publish(key, msg)

    deliver(0, [1, 3])  # before the start: queued, taken once the loop runs
    codes: list[int] = []
    thread = threading.Thread(target=lambda: codes.append(logger.run(Lockstep(watch_s=0.01))))
    thread.start()
    netem.declare_start()
    try:
        deliver(2, [3])  # ahead: kept until epoch 1 is taken
        deliver(1, [1])
    finally:
        thread.join(10)
    assert codes == [0]
    assert logger.lines == [
        "epoch 0: agent 2 got states from [1, 3]",
        "epoch 1: agent 2 got states from [1]",
        "epoch 2: agent 2 got states from [3]",
    ]
    assert dict(svc.malformed.counts) == {}
