"""A packet an agent sent late because it waited for its robot's pose is marked so, and a
receiver counts it as the robot's silence, not as the testbed's late sender."""

from __future__ import annotations

import contextlib
import time
from collections import Counter
from pathlib import Path

import numpy as np
import orjson

from agent.node import AgentNode
from agent.outgoing import Reports, state_messages
from formation import keys
from formation.codec import now_ns
from formation.deadlines import ROBOT_SILENT
from formation.messages import CoordinationState, DeliveredPacket, Delivery, TokenReport
from formation.realtime import Clock
from formation.scenario import Scenario
from shell import Incoming, MemoryBus, Realtime, Service

RUN = "silent"
ROOT = Path(__file__).resolve().parents[3]


def _late_state(sender: Service, netem: Service, robot_silent: bool) -> Incoming:
    """Agent 2's state of epoch 0, sent now (ten periods late), delivered to agent 1."""
    seq = sender.next_seq(keys.agent_state(RUN, 2))
    state = _state(sender.header_format(), seq, now_ns(), robot_silent)
    packet = DeliveredPacket(source=2, seq=seq, sent_epoch=0, message=state.decode())
    key = keys.inbox(RUN, 1, "state")
    msg = Delivery(**netem.header(key, 0), receiver=1, phase="state", packets=[packet], lost=[])
    return Incoming(key, msg.model_dump_json().encode(), None, time.time_ns())


def test_a_late_state_marked_robot_silent_is_the_robots_and_an_unmarked_one_the_senders() -> None:
    bus = MemoryBus()
    netem, sender = Service(bus, RUN, "netem", 0), Service(bus, RUN, "agent", 2)
    receiver = Service(bus, RUN, "agent", 1)
    timing = Realtime(period_s=1.0)
    timing.clock = Clock(time.time_ns() - 10 * 10**9, 10**9)  # epoch 0 is ten periods ago
    counts: Counter[str] = Counter()
    inbox = timing.inbox(receiver, [1], counts)
    take = inbox.take("state", 0)
    next(take)
    with contextlib.suppress(StopIteration):
        take.send(False)  # epoch 0 taken, with nothing in it
    inbox.route(_late_state(sender, netem, robot_silent=True))
    assert counts[ROBOT_SILENT] == 1 and counts["late_sender"] == 0
    inbox.route(_late_state(sender, netem, robot_silent=False))
    assert counts[ROBOT_SILENT] == 1 and counts["late_sender"] == 1


def _state(head: bytes, seq: int, stamp_ns: int, robot_silent: bool) -> bytes:
    """Agent 2's state of epoch 0 at (1, 2)."""
    positions = np.array([[1.0, 2.0]])
    return state_messages(head, [seq], 0, stamp_ns, [2], positions, [[]], None, robot_silent)[0]


def _report(head: bytes, robot_silent: bool) -> bytes:
    """Agent 2's report of epoch 0, with no in-link."""
    reports = Reports([2], [], [])
    return reports.messages(head, [0], 0, 1, np.zeros(0, bool), np.zeros((0, 2)), robot_silent)[0]


def test_the_mark_is_on_the_wire_only_when_set_and_both_messages_carry_it() -> None:
    head = Service(MemoryBus(), RUN, "agent", 2).header_format()
    assert b"robot_silent" not in _state(head, 0, 1, robot_silent=False)
    assert CoordinationState.model_validate_json(_state(head, 0, 1, robot_silent=True)).robot_silent
    assert TokenReport.model_validate_json(_report(head, robot_silent=True)).robot_silent
    assert not TokenReport.model_validate_json(_report(head, robot_silent=False)).robot_silent


def test_an_agent_marks_what_it_sends_late_after_a_robot_wait_until_it_is_in_time_again() -> None:
    scenario = Scenario.from_file(ROOT / "scenarios/paper.toml").with_overrides(
        runtime={"mode": "realtime", "realtime_period_s": 1.0}
    )
    bus = MemoryBus()
    heard: list[bool] = []
    bus.declare_subscriber(
        keys.agent_state(RUN, 1),
        lambda sample: heard.append(
            bool(orjson.loads(sample.payload.to_bytes()).get("robot_silent"))
        ),
    )
    node = AgentNode(Service(bus, RUN, "agent", 1), scenario, [1], "hold", seed=1)
    timing = Realtime(period_s=1.0)
    node._timing = timing
    timing.clock = Clock(time.time_ns() - 10 * 10**9, 10**9)  # epoch 0 is ten periods ago
    node._publish_states()  # late, but no wait for the robot: the testbed's
    node.robot_waited = True  # as _move_bodies sets it after a stale wait
    node._publish_states()  # late after the wait: the robot's
    timing.clock = Clock(time.time_ns() + 10**9, 10**9)  # epoch 0 is still to come
    node._publish_states()  # in time: the mark ends
    timing.clock = Clock(time.time_ns() - 10 * 10**9, 10**9)
    node._publish_states()  # late again, with no new wait: the testbed's
    assert heard == [False, True, False, False]
