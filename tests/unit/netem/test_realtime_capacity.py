"""Realtime capacity queues, without Zenoh: netem holds each packet until it leaves its queues,
and an ``oldest`` queue that is full pushes out the oldest packet it still holds for the new
one (docs/model.md §9), which is then recorded as ``queue_full`` and never forwarded."""

from __future__ import annotations

import math
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from formation import keys
from formation.capacity import Capacity
from formation.codec import Malformed, attachment
from formation.messages import DeliveredPacket
from formation.realtime import Clock
from formation.scenario import Scenario
from netem.links.capacity import QueueParams, serve_queue
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
    # a pushed-out packet leaves every queue that still holds it: the medium holds 1 and 4;
    # 2 and 3 had crossed the radio when the medium pushed them out, and took its time
    radio, medium = net.states[1], net.states[0]
    assert radio is not None and medium is not None
    assert len(radio.backlog_s) == 4 and len(medium.backlog_s) == 2
    # in lockstep (no token) a decided packet is never taken back: the newest is refused
    net = CapacityNetwork(caps, 4, links, 10.0)
    verdicts = [net.alone(0, "estimate", (0, i), 100) for i in range(1, 4)]
    assert [v.reason for v in verdicts] == ["", "", "queue_full"]


def _forwarder(
    policy: str, limit_packets: int = 2
) -> tuple[RealtimeForwarder, list[int], list[Record]]:
    paper = Scenario.from_file(ROOT / "scenarios/paper.toml")
    scenario = paper.with_overrides(network={"capacity": [ap(policy, limit_packets)]})
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


def _five_reports_at_once(rt: RealtimeForwarder) -> None:
    """Five reports at once, each 0.3 s on the wire; then every held packet leaves or is gone."""
    due: list[Due] = rt._due
    now = time.time_ns()
    for i in range(1, 6):
        msg = Incoming(keys.agent_report(RUN, i), PAYLOAD, attachment(0, 0, i), now)
        rt.handle(msg, due)
    deadline = time.monotonic() + 5.0
    while due and time.monotonic() < deadline:
        time.sleep(0.01)
        rt.tick()
    rt.tick()
    assert not due


@pytest.mark.parametrize(("policy", "kept"), [("oldest", {1, 5}), ("tail", {1, 2})])
def test_a_full_queue_keeps_the_newest_under_oldest_and_records_the_pushed_out(
    policy: str, kept: set[int]
) -> None:
    rt, delivered, records = _forwarder(policy)
    _five_reports_at_once(rt)  # into room for two
    assert set(delivered) == kept and len(delivered) == 2
    fates = {src: (d.verdict, d.model) for src, _, _, _, _, d in records}
    assert len(records) == 5  # one record each, held ones once they left
    for src in range(1, 6):
        want = ("pass", "") if src in kept else ("drop", "queue_full")
        assert fates[src] == want, src
    assert rt.deadline["queue_drops"] == 3
    assert sum(n for (cls, _, _), n in rt.ledger.forwarded.items() if cls == "report") == 2


def realtime(
    caps: list[dict[str, Any]], link: tuple[int, int], arrivals: list[float], payloads: list[int]
) -> list[float]:
    """Each packet's departure from its last queue [s] (NaN: dropped) as realtime netem finds
    them, one packet at a time, with the departures the later ones gave back."""
    net = CapacityNetwork([Capacity.model_validate(c) for c in caps], 4, [(1, 2), (2, 1)], 1.0)
    left: list[float] = []
    for token, (t, payload) in enumerate(zip(arrivals, payloads, strict=True)):
        _, leaves, pushed = net.arrive(link, payload, t, 0, math.inf, token=token)
        left.append(leaves)
        for victim in pushed:
            left[victim] = math.nan
        for held, leaves in net.retimed().items():
            left[held] = leaves
    return left


@settings(max_examples=40, deadline=None)
@given(
    gaps=st.lists(st.sampled_from([0.0, 0.0, 0.0005, 0.001, 0.004, 0.02]), min_size=2, max_size=60),
    sizes=st.lists(st.integers(40, 1400), min_size=60, max_size=60),
    burst=st.sampled_from([0, 1500, 4000]),
    limit=st.sampled_from([("limit_packets", 1), ("limit_packets", 3), ("limit_bytes", 3000)]),
)
def test_realtime_oldest_gives_a_pushed_out_packets_time_back_as_the_model_does(
    gaps: list[float], sizes: list[int], burst: int, limit: tuple[str, int]
) -> None:
    arrivals = np.cumsum(gaps).tolist()
    payloads = sizes[: len(arrivals)]
    cap = {"scope": "link", "link": [1, 2], "rate_bps": 1e6, "burst_bytes": burst,
           limit[0]: limit[1], "policy": "oldest", "overhead_bytes": 42}  # fmt: skip
    params = QueueParams(1e6, burst, overhead_bytes=42, policy="oldest", **{limit[0]: limit[1]})
    model = serve_queue(params, arrivals, payloads)
    np.testing.assert_array_equal(realtime([cap], (1, 2), arrivals, payloads), model.departure_s)


@settings(max_examples=40, deadline=None)
@given(
    gaps=st.lists(st.sampled_from([0.0, 0.0, 0.0005, 0.001, 0.004, 0.02]), min_size=2, max_size=60),
    sizes=st.lists(st.integers(40, 1400), min_size=60, max_size=60),
    burst=st.sampled_from([0, 4000]),
)
def test_realtime_gives_time_back_in_the_queues_after_the_one_that_pushed_out(
    gaps: list[float], sizes: list[int], burst: int
) -> None:
    # a link queue, then its sender's radio: the radio serves what the link queue lets go
    arrivals = np.cumsum(gaps).tolist()
    payloads = np.array(sizes[: len(arrivals)])
    link = {"scope": "link", "link": [1, 2], "rate_bps": 1e6, "burst_bytes": burst,
            "limit_packets": 3, "policy": "oldest", "overhead_bytes": 42}  # fmt: skip
    radio = {"scope": "radio", "agent": 1, "rate_bps": 4e6, "overhead_bytes": 42}
    first = serve_queue(
        QueueParams(1e6, burst, limit_packets=3, overhead_bytes=42, policy="oldest"),
        arrivals,
        payloads,
    )
    passed = first.passed
    second = serve_queue(
        QueueParams(4e6, overhead_bytes=42), first.departure_s[passed], payloads[passed]
    )
    want = np.full(len(arrivals), np.nan)
    want[passed] = second.departure_s
    got = realtime([link, radio], (1, 2), arrivals, payloads.tolist())
    np.testing.assert_array_equal(got, want)


def test_a_train_into_a_full_oldest_queue_is_not_starved() -> None:
    # 10 trains of 20 packets at 4 times the rate, 0.1 s apart: each train ends with the
    # queue full, every packet of the next pushing out the oldest; realtime kept each
    # pushed-out packet's link time, so the next ones waited ever longer
    arrivals = [0.1 * train + 0.002 * k for train in range(10) for k in range(20)]
    cap = {"scope": "link", "link": [1, 2], "rate_bps": 1e6, "burst_bytes": 3000,
           "limit_packets": 4, "policy": "oldest"}  # fmt: skip
    left = np.array(realtime([cap], (1, 2), arrivals, [1000] * len(arrivals)))
    model = serve_queue(QueueParams(1e6, 3000, limit_packets=4, policy="oldest"), arrivals,
                        [1000] * len(arrivals))  # fmt: skip
    np.testing.assert_array_equal(left, model.departure_s)
    assert np.isfinite(left).sum() == model.passed.sum() > 100


def test_a_held_packet_leaves_earlier_once_one_ahead_of_it_is_pushed_out() -> None:
    # room for three: 1 on the wire until 0.3 s; 4 pushes out 2 and 3 moves up to leave at
    # 0.6 s (not 0.9), 5 pushes out 3 and 4 moves up to 0.6 s, 5 leaves at 0.9 s
    rt, delivered, records = _forwarder("oldest", limit_packets=3)
    _five_reports_at_once(rt)
    assert delivered == [1, 4, 5]
    sojourn_ms = {src: d.sojourn_ms for src, _, _, _, _, d in records if d.verdict == "pass"}
    assert sojourn_ms.keys() == {1, 4, 5}
    for src, want in ((1, 300.0), (4, 600.0), (5, 900.0)):
        assert abs(sojourn_ms[src] - want) < 10.0, (src, sojourn_ms)  # arrivals µs apart
