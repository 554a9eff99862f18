"""A scenario's queues over the phases of its epochs (docs/model.md §9)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from formation.capacity import Capacity
from formation.codec import decode
from formation.errors import LinkModelError
from formation.messages import DecisionBatch, decision_rows
from netem.links.capacity_network import CapacityNetwork, packet_kind
from netem.links.capacity_plan import capacity_plan
from netem.links.layer_stack import Outcome
from netem.proxy.records import decision_batch, queued

N = 4
FORMATION = [(1, 2), (2, 1), (2, 3), (3, 2), (3, 4), (4, 3), (1, 4), (4, 1)]
PASS = Outcome(True, 0, 0.0, 1, "pass", "", "")


def network(*entries: dict[str, object], period_s: float = 1.0) -> CapacityNetwork:
    caps = [Capacity.model_validate(e) for e in entries]
    return CapacityNetwork(caps, N, FORMATION, period_s)


def test_reports_past_the_report_deadline_are_late() -> None:
    # 8,000 bit/s = 1,000 B/s; reports of 100 B leave every 0.1 s from 0.20 s, due at 0.60 s
    net = network({"scope": "medium", "medium": "ap", "links": "control", "rate_bps": 8000.0})
    verdicts = net.phase(0, "report", [((i, 0), 100) for i in (4, 3, 2, 1)])
    # served in link order (1, 0), (2, 0), ...: the k-th leaves at 0.20 + 0.1 k
    assert [v.reason for v in verdicts] == ["", "", "", ""]
    # 110 B: 0.11 s each; due 0.40 s after the phase's start
    verdicts = net.phase(1, "report", [((i, 0), 110) for i in range(1, 5)] * 2)
    in_time = math.floor((0.60 - 0.20) / 0.11)
    assert [v.reason for v in sorted(verdicts, key=lambda v: v.sojourn_ms)] == [""] * in_time + [
        "queue_late"
    ] * (8 - in_time)
    assert sorted(v.sojourn_ms for v in verdicts) == pytest.approx([110.0 * k for k in range(1, 9)])
    assert {v.queue for v in verdicts} == {"medium ap"}


def test_a_packet_crosses_its_link_radio_and_medium_in_turn() -> None:
    net = network(
        {"scope": "link", "link": [1, 2], "rate_bps": 8000.0},  # 100 B: 0.1 s
        {"scope": "radio", "agent": 1, "rate_bps": 16000.0},  # 0.05 s
        {"scope": "medium", "medium": "mesh", "links": "formation", "rate_bps": 80000.0},
        period_s=10.0,
    )
    (one,) = net.phase(0, "state", [((1, 2), 100)])
    assert one.reason == "" and one.queue == "medium mesh"
    assert one.sojourn_ms == pytest.approx(100.0 + 50.0 + 10.0)


def test_a_full_queue_drops_with_its_depth() -> None:
    net = network({"scope": "radio", "agent": 0, "rate_bps": 8000.0, "limit_packets": 2})
    verdicts = net.phase(0, "estimate", [((0, i), 100) for i in range(1, 5)])
    assert [(v.reason, v.depth) for v in verdicts] == [
        ("", 0),
        ("", 1),
        ("queue_full", 2),
        ("queue_full", 2),
    ]


def test_phases_go_in_order() -> None:
    net = network({"scope": "radio", "agent": 1, "rate_bps": 8000.0})
    net.phase(3, "report", [((1, 0), 10)])
    with pytest.raises(LinkModelError, match=r"state of epoch 3 after \(3, 1\)"):
        net.phase(3, "state", [((1, 2), 10)])


def test_a_queues_backlog_carries_into_the_next_phase() -> None:
    # states of 150 B on agent 1's radio at 8,000 bit/s leave at 0.15, 0.30, 0.45 s (due 0.20)
    net = network({"scope": "radio", "agent": 1, "rate_bps": 8000.0, "limit_packets": 3})
    first = net.phase(0, "state", [((1, 2), 150), ((1, 4), 150), ((1, 4), 150)])
    assert [v.reason for v in first] == ["", "queue_late", "queue_late"]
    report = net.phase(0, "report", [((1, 0), 100)])  # at 0.2 s two are still queued
    assert report[0].depth == 2 and report[0].reason == ""
    assert report[0].sojourn_ms == pytest.approx(350.0)  # behind them: leaves at 0.55 s


def test_the_plan_judges_only_what_the_models_passed() -> None:
    from formation.scenario import load_dict

    data = {
        "agents": [{"id": i, "offset": o} for i, o in enumerate([[0, 0], [1, 0], [0, 1]], 1)],
        "edges": [[1, 2], [2, 3], [1, 3]],
        "epochs": 4,
        "network": {
            "capacity": [{"scope": "radio", "agent": 1, "rate_bps": 40000.0, "limit_packets": 1}]
        },
    }
    s = load_dict(data)
    links = np.concatenate(
        [s.directed_links, [[i, 0] for i in (1, 2, 3)], [[0, i] for i in (1, 2, 3)]]
    )
    passed = np.ones((4, links.shape[0]), dtype=bool)
    codes = capacity_plan(s, passed, links)
    out1 = [r for r, (a, _) in enumerate(links.tolist()) if a == 1]
    # agent 1's radio holds one packet: one of its two states, then its report, get through
    assert (codes[:, out1] == 0).sum(axis=1).tolist() == [2, 2, 2, 2]
    assert (codes[:, [r for r in range(links.shape[0]) if r not in out1]] == 0).all()
    passed[:, out1[0]] = False  # a packet the models dropped never reaches the queue
    assert (capacity_plan(s, passed, links)[:, out1[0]] == 0).all()


def test_a_queued_decision_is_a_valid_record() -> None:
    d = queued(PASS, "queue_full", "medium ap", 3, 12.5)
    batch = decision_batch(
        {"run_id": "r", "sender": "netem", "seq": 0, "epoch": 2, "stamp_ns": 1},
        "report",
        [(3, 0, "report", 2, 7, d)],
    )
    (rec,) = decision_rows(decode(batch, DecisionBatch))
    assert (rec.verdict, rec.model, rec.queue, rec.queue_depth, rec.sojourn_ms) == (
        "drop",
        "queue_full",
        "medium ap",
        3,
        12.5,
    )
    ok = queued(PASS, "", "medium ap", 0, 1.0)
    assert ok.delivered and ok.verdict == "pass" and ok.copies == 1


def test_packet_kinds() -> None:
    assert packet_kind((3, 0)) == ("report", 3)
    assert packet_kind((0, 3)) == ("estimate", 3)
    assert packet_kind((2, 3)) == ("state", 2)


def test_a_change_takes_effect_from_its_epoch_and_a_new_link_queue_too() -> None:
    net = network({"scope": "radio", "agent": 0, "rate_bps": 8e6})
    slow = Capacity.model_validate({"scope": "radio", "agent": 0, "rate_bps": 800.0})
    assert net.change(slow, from_epoch=2) == [(0, 1), (0, 2), (0, 3), (0, 4)]
    assert net.phase(1, "estimate", [((0, 1), 100)])[0].reason == ""  # before its epoch
    assert net.phase(2, "estimate", [((0, 1), 100)])[0].reason == "queue_late"  # 1 s > 0.25 s
    added = Capacity.model_validate({"scope": "link", "link": [1, 2], "rate_bps": 800.0})
    assert net.change(added, from_epoch=4) == [(1, 2)]
    assert not net.constrained((1, 2), 3) and net.constrained((1, 2), 4)
    assert net.phase(3, "state", [((1, 2), 100)])[0].queue == ""  # no queue yet
    assert net.phase(4, "state", [((1, 2), 100)])[0].reason == "queue_late"
    with pytest.raises(ValueError, match=r"radio 3: no such queue"):
        net.change(Capacity.model_validate({"scope": "radio", "agent": 3, "rate_bps": 1.0}), 5)


@settings(max_examples=150, deadline=None)
@given(
    rates=st.lists(st.sampled_from([800.0, 8_000.0, 80_000.0, 8e6]), min_size=2, max_size=2),
    bursts=st.lists(st.sampled_from([0, 0, 150, 400]), min_size=2, max_size=2),
    limit_bytes=st.sampled_from([None, 120, 1_000]),
    overhead=st.sampled_from([0, 30]),
    sent=st.lists(st.tuples(st.booleans(), st.integers(60, 140)), min_size=1, max_size=30),
    change_at=st.integers(0, 30),
    changed_rate=st.sampled_from([800.0, 8e6]),
)
def test_a_link_alone_in_its_queues_is_judged_at_once_as_its_phase_would(
    rates: list[float],
    bursts: list[int],
    limit_bytes: int | None,
    overhead: int,
    sent: list[tuple[bool, int]],
    change_at: int,
    changed_rate: float,
) -> None:
    entries = (
        {"scope": "link", "link": [1, 2], "rate_bps": rates[0], "burst_bytes": bursts[0],
         "limit_bytes": limit_bytes, "overhead_bytes": overhead},
        {"scope": "medium", "medium": "m", "links": [[1, 2]], "rate_bps": rates[1],
         "burst_bytes": bursts[1]},
    )  # fmt: skip
    at_once, by_phase = network(*entries, period_s=0.1), network(*entries, period_s=0.1)
    assert (1, 2) in at_once.solo and not at_once.phases
    slower = Capacity.model_validate({**entries[0], "rate_bps": changed_rate})
    for epoch, (passed, payload) in enumerate(sent):
        if epoch == change_at:  # the closed form's states, taken over by the full judgement
            for net in (at_once, by_phase):
                net.change(slower, from_epoch=epoch + 1)
        if passed:  # else the models dropped it: no queue sees it
            got = at_once.alone(epoch, "state", (1, 2), payload)
            assert got == by_phase.phase(epoch, "state", [((1, 2), payload)])[0], epoch


@settings(max_examples=60, deadline=None)
@given(
    rate=st.sampled_from([3_000.0, 6_000.0, 10_000.0, 11_000.0, 8e6]),
    overhead=st.sampled_from([0, 30]),
    first=st.integers(0, 2_000),
    phase=st.sampled_from(["state", "report"]),
    period_s=st.sampled_from([0.1, 1.0]),
)
def test_a_block_in_closed_form_is_what_alone_gives_packet_by_packet(
    rate: float, overhead: int, first: int, phase: str, period_s: float
) -> None:
    link = (1, 2) if phase == "state" else (1, 0)
    entry = {"scope": "link", "link": list(link), "rate_bps": rate, "overhead_bytes": overhead}
    epochs = np.arange(first, first + 40, dtype=np.int64)
    payloads = 200 + (epochs // 7) % 3  # sizes change now and then
    block = network(entry, period_s=period_s).fixed(link, phase, epochs, payloads)
    one_by_one = network(entry, period_s=period_s)
    verdicts = [
        one_by_one.alone(int(e), phase, link, int(p)) for e, p in zip(epochs, payloads, strict=True)
    ]
    if block is None:  # a packet needs more than half a period
        assert 8 * (int(payloads.max()) + overhead) / rate > 0.5 * period_s * (1 - 1e-9)
        return
    assert [(v.reason, v.queue, v.depth, v.sojourn_ms) for v in verdicts] == [
        (r, block.queue, 0, s) for r, s in zip(block.reason, block.sojourn_ms, strict=True)
    ]
    assert one_by_one.last_in[link] == (
        block.t0_s[-1],
        block.payload_bytes[-1],
        block.departure_s[-1],
    )
