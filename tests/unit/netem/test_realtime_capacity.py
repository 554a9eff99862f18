"""Realtime capacity queues, without Zenoh: netem holds each packet until it leaves its queues,
and an ``oldest`` queue that is full pushes out the oldest packet it still holds for the new
one (docs/model.md §9), which is then recorded as ``queue_full`` and never forwarded."""

from __future__ import annotations

import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from formation import keys
from formation.capacity import Capacity
from formation.codec import Malformed, attachment
from formation.messages import DeliveredPacket
from formation.realtime import Clock
from formation.scenario import Scenario
from netem.links.capacity_network import CapacityNetwork
from netem.proxy.progress import Progress
from netem.proxy.realtime import Due, RealtimeForwarder
from netem.proxy.records import Ledger, Record
from netem.proxy.routes import Links, Routes
from shell import Incoming

ROOT = Path(__file__).resolve().parents[3]
RUN = "rtcap"
PAYLOAD = b'{"report": "' + b"x" * 88 + b'"}'  # 102 B: 0.3 s at 2,720 bit/s


def ap(policy: str, limit_packets: int = 2) -> dict[str, Any]:
    return {"scope": "medium", "medium": "ap", "links": "control", "rate_bps": 2_720.0,
            "limit_packets": limit_packets, "policy": policy}  # fmt: skip


def test_oldest_pushes_out_the_oldest_held_packet_of_any_earlier_arrival() -> None:
    links = [(1, 2), (2, 1)]
    caps = [Capacity.model_validate(ap("oldest")),
            Capacity.model_validate({"scope": "radio", "agent": 0, "rate_bps": 1e6})]  # fmt: skip
    net = CapacityNetwork(caps, 4, links, 1.0)
    # four estimates at once: the first on the wire, each later one pushes out the one before
    got = [net.arrive((0, i), 100, 0.0, 0, 10.0, token=i) for i in range(1, 5)]
    assert [pushed for _, _, pushed in got] == [[], [], [2], [3]]
    assert [v.reason for v, _, _ in got] == ["", "", "", ""]
    # a pushed-out packet leaves every queue: the radio's backlog holds 1 and 4 only
    radio, medium = net.states[1], net.states[0]
    assert radio is not None and medium is not None
    assert len(radio.backlog_s) == 2 and len(medium.backlog_s) == 2
    # in lockstep (no token) a decided packet is never taken back: the newest is refused
    net = CapacityNetwork(caps, 4, links, 10.0)
    verdicts = [net.alone(0, "estimate", (0, i), 100) for i in range(1, 4)]
    assert [v.reason for v in verdicts] == ["", "", "queue_full"]


def _forwarder(policy: str) -> tuple[RealtimeForwarder, list[int], list[Record]]:
    paper = Scenario.from_file(ROOT / "scenarios/paper.toml")
    scenario = paper.with_overrides(network={"capacity": [ap(policy)]})
    links = Links(scenario, seed=1)
    delivered: list[int] = []
    records: list[Record] = []

    def deliver(phase: str, receiver: int, epoch: int, packets: list[bytes], *_: Any) -> None:
        delivered.extend(DeliveredPacket.model_validate_json(p).source for p in packets)

    rt = RealtimeForwarder(
        SimpleNamespace(malformed=Malformed()),  # type: ignore[arg-type]  # only its counts
        links, Routes(links.agents), Progress(links.agents, scenario.epochs, lambda: None),
        Ledger(), lambda phase, epoch, batch: records.extend(batch), deliver,
    )  # fmt: skip
    rt.clock = Clock(time.time_ns(), 10_000_000_000)  # deadlines far ahead
    return rt, delivered, records


@pytest.mark.parametrize(("policy", "kept"), [("oldest", {1, 5}), ("tail", {1, 2})])
def test_a_full_queue_keeps_the_newest_under_oldest_and_records_the_pushed_out(
    policy: str, kept: set[int]
) -> None:
    rt, delivered, records = _forwarder(policy)
    due: list[Due] = rt._due
    now = time.time_ns()
    for i in range(1, 6):  # five reports at once into room for two, each 0.3 s on the wire
        msg = Incoming(keys.agent_report(RUN, i), PAYLOAD, attachment(0, 0, i), now)
        rt.handle(msg, due)
    deadline = time.monotonic() + 5.0
    while due and time.monotonic() < deadline:  # every held packet leaves, or is gone
        time.sleep(0.01)
        rt.tick()
    rt.tick()
    assert not due
    assert set(delivered) == kept and len(delivered) == 2
    fates = {src: (d.verdict, d.model) for src, _, _, _, _, d in records}
    assert len(records) == 5  # one record each, held ones once they left
    for src in range(1, 6):
        want = ("pass", "") if src in kept else ("drop", "queue_full")
        assert fates[src] == want, src
    assert rt.deadline["queue_drops"] == 3
    assert sum(n for (cls, _, _), n in rt.ledger.forwarded.items() if cls == "report") == 2
