"""netem's realtime forwarding, without Zenoh: a burst of states leaves as one delivery per
receiver holding each packet its links passed, and a packet put out after its deadline
though it was ready in time is netem's own miss."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from types import SimpleNamespace

import pytest

from formation import keys
from formation.codec import Malformed, attachment, encode
from formation.messages import CoordinationState, DeliveredPacket
from formation.realtime import ESTIMATE_DEADLINE, REPORT_DEADLINE, Clock
from formation.scenario import Scenario
from netem.proxy.loop import run_loop
from netem.proxy.progress import Progress
from netem.proxy.realtime import PREPARE_AHEAD, RECORDS_AT, START_LEAD_S, Due, RealtimeForwarder
from netem.proxy.records import Ledger
from netem.proxy.routes import Links, Routes
from shell import Incoming
from shell import Realtime as RealtimeTime

ROOT = Path(__file__).resolve().parents[3]
RUN = "batch"


def _rig(clock: Clock) -> tuple[RealtimeForwarder, list[tuple[str, int, int, list[bytes]]], Links]:
    scenario = Scenario.from_file(ROOT / "scenarios/grid20.toml")
    links = Links(scenario, seed=1)
    sent: list[tuple[str, int, int, list[bytes]]] = []
    rt = RealtimeForwarder(
        SimpleNamespace(malformed=Malformed()),  # type: ignore[arg-type]  # only its counts
        links, Routes(links.agents), Progress(links.agents, scenario.epochs, lambda: None),
        Ledger(), lambda *_: None,
        lambda phase, receiver, epoch, packets, lost, dead: sent.append((phase, receiver, epoch, packets)),
    )  # fmt: skip
    rt.clock = clock
    return rt, sent, links


def _burst(rt: RealtimeForwarder, links: Links, epoch: int, arrived_ns: int) -> dict[int, bytes]:
    payloads = {}
    for i in links.agents:
        payloads[i] = encode(CoordinationState(run_id=RUN, sender=f"agent/{i}", seq=epoch,
                                               epoch=epoch, stamp_ns=0, agent=i,
                                               position=[float(i), 0.5]))  # fmt: skip
        msg = Incoming(
            keys.agent_state(RUN, i), payloads[i], attachment(epoch, epoch, i), arrived_ns
        )
        due: list[Due] = []
        rt.handle(msg, due)
        assert not due  # grid20 delays nothing
    return payloads


def test_a_burst_goes_out_as_one_delivery_per_receiver() -> None:
    now = time.time_ns()
    rt, sent, links = _rig(Clock(now, 10_000_000_000))  # deadlines far ahead
    payloads = _burst(rt, links, 0, now)
    assert sent == []  # nothing before the flush
    rt.flush()
    receivers = [r for _, r, _, _ in sent]
    assert sorted(receivers) == sorted(set(receivers))  # one delivery each
    got = {
        (p.source, r): p
        for _, r, _, packets in sent
        for p in map(DeliveredPacket.model_validate_json, packets)
    }
    passed = {(s, r) for (cls, s, r), n in rt.ledger.forwarded.items() if cls == "formation" and n}
    assert set(got) == passed and len(passed) > len(receivers)  # fewer messages than packets
    assert passed < {(s, r) for r in links.agents for s in links.in_links[r]}  # grid20 drops
    for (s, _), p in got.items():
        assert (p.sent_epoch, p.seq, p.copies) == (0, 0, 1)
        assert p.message.encode() == payloads[s]  # the sender's payload, unparsed
    assert {(phase, epoch) for phase, _, epoch, _ in sent} == {("state", 0)}
    assert rt.deadline["late_forwards"] == 0


def test_a_packet_ready_in_time_but_put_out_late_is_netems_miss() -> None:
    now = time.time_ns()
    period = 1_000_000_000
    rt, sent, links = _rig(Clock(now - period, period))  # epoch 0's state deadline has passed
    _burst(rt, links, 0, arrived_ns=now - period)  # arrived at epoch 0's start: in time
    rt.flush()
    delivered = sum(len(packets) for *_, packets in sent)
    assert delivered == rt.deadline["late_forwards"] > 0


@pytest.mark.parametrize("wait_ns", [0, 10**12])
def test_a_flush_waits_only_as_long_as_asked(wait_ns: int) -> None:
    now = time.time_ns()
    rt, sent, links = _rig(Clock(now, 10_000_000_000))
    _burst(rt, links, 0, now)
    rt.flush(unless_newer_than_ns=wait_ns)
    assert bool(sent) == (wait_ns == 0)


def test_the_decision_records_go_out_when_netem_idles() -> None:
    """Once a period, at RECORDS_AT of it (after the early estimates and states, before the
    estimate deadline's late steps), not at the period's start, in the states' burst."""
    published: list[int] = []
    rt, _, _ = _rig(Clock(0, 1))
    rt.publish_records = lambda phase, epoch, records: published.append(time.time_ns())
    rt.ledger.decisions[("state", 0)].append((1, 2, "formation", 0, 0, None))  # type: ignore[arg-type]
    service = SimpleNamespace(
        stopping=threading.Event(),
        declare_start=lambda: None,
        next_incoming=lambda timeout: time.sleep(timeout),
    )
    rt.service = service  # type: ignore[assignment]
    began = time.time_ns()
    timing = RealtimeTime(1.0)  # a window of 150 ms, wide enough for a loaded machine
    assert run_loop(service, timing, rt, lambda: True, lambda: None, lambda: bool(published)) == 0  # type: ignore[arg-type]
    assert rt.clock is not None
    assert rt.clock.t0_ns - began >= START_LEAD_S * 1e9  # time for every agent to fetch it
    (at,) = published
    assert REPORT_DEADLINE < RECORDS_AT < ESTIMATE_DEADLINE
    assert rt.clock.at(0, RECORDS_AT) <= at < rt.clock.at(0, ESTIMATE_DEADLINE)


def test_decision_blocks_are_computed_ahead_a_share_of_links_per_epoch() -> None:
    """A new block of decisions (epoch N = 3 blocks in) is computed for every link by the
    preparations of epochs N - PREPARE_AHEAD .. N - 1, a share of the links in each; the
    decisions stay what they would be computed on demand."""
    rt, _, links = _rig(Clock(0, 1))
    block = 1024  # LinkModel's default block_epochs
    needed = 3 * block
    assert not any(m.prepared(needed) for m in links.models.values())
    for k in range(needed - PREPARE_AHEAD, needed):
        assert not all(m.prepared(needed) for m in links.models.values())
        rt.prepare(k)
    assert all(m.prepared(needed) for m in links.models.values())
    fresh = Links(Scenario.from_file(ROOT / "scenarios/grid20.toml"), seed=1)
    for link, model in links.models.items():  # the same decisions as computed on demand
        assert model.decide(needed) == fresh.models[link].decide(needed)
