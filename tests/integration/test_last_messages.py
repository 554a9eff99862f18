"""A sender leaves only once netem has its last messages: netem's ``netem/final`` queryable and
the agent's republishing, each driven directly over a real Zenoh session."""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from pathlib import Path

import pytest

from agent.node import AgentNode
from formation import keys
from formation.codec import attachment, encode, now_ns
from formation.messages import CoordinationState
from formation.scenario import Scenario
from leader.node import LeaderNode
from netem.node import FINAL_WAIT_S, NetemNode
from testkit.zenoh_peer import peer_service

pytestmark = pytest.mark.integration
ROOT = Path(__file__).resolve().parents[2]
RUN = "last-messages"


def _final_state(i: int, epochs: int) -> tuple[str, bytes, bytes]:
    msg = CoordinationState(run_id=RUN, sender=f"agent/{i}", seq=epochs, epoch=epochs,
                            stamp_ns=now_ns(), agent=i, position=[float(i), 0.0])  # fmt: skip
    return keys.agent_state(RUN, i), encode(msg), attachment(epochs, epochs, i)


@pytest.fixture
def scenario() -> Scenario:
    return Scenario.from_file(ROOT / "scenarios/paper.toml").with_overrides(epochs=10)


def test_netem_says_which_final_states_it_lacks(scenario: Scenario) -> None:
    final_key = keys.netem_final(RUN)
    with peer_service(RUN, "netem", 0) as svc:
        node = NetemNode(svc, scenario, seed=1, wait_for_recorder=False)
        assert svc.ask(final_key, {"agents": [1, 2]}) == {"missing": [1, 2], "estimates_done": 0}
        node._handle(*_final_state(1, scenario.epochs))
        assert svc.ask(final_key, {"agents": [1, 2]})["missing"] == [2]
        # A final state that arrives while the query waits is counted before the answer.
        late = threading.Timer(FINAL_WAIT_S / 5, node._handle, _final_state(2, scenario.epochs))
        late.start()
        try:
            assert svc.ask(final_key, {"agents": [1, 2]})["missing"] == []
        finally:
            late.join()
        assert svc.ask(final_key, {"estimates": True})["estimates_done"] == 0
        # A malformed question gets an error, is counted, and changes nothing.
        assert svc.ask(final_key, {"agents": "two"}) is None
        assert svc.malformed.counts[final_key] == 1
        assert node.final_states == {1, 2}


@pytest.mark.parametrize("answers", [[[2], []], [[2], [2], [2]]], ids=["acked", "never"])
def test_an_agent_republishes_the_final_states_netem_lacks(
    scenario: Scenario, answers: list[list[int]]
) -> None:
    published: Counter[int] = Counter()
    asked = []
    lock = threading.Lock()

    def on_state(sample) -> None:  # type: ignore[no-untyped-def]
        with lock:
            published[int(str(sample.key_expr).split("/")[-2])] += 1

    def on_final(query) -> None:  # type: ignore[no-untyped-def]
        with lock:
            asked.append(query.payload.to_bytes())
            missing = answers[min(len(asked), len(answers)) - 1]
        query.reply(query.key_expr, f'{{"missing": {missing}, "estimates_done": 10}}'.encode())

    with peer_service(RUN, "pool", 1) as svc:
        node = AgentNode(svc, scenario, [1, 2], "estimate", seed=1)
        sub = svc.session.declare_subscriber(keys.agent_state(RUN, "*"), on_state)
        qbl = svc.session.declare_queryable(keys.netem_final(RUN), on_final)
        try:
            confirmed = node.confirm_final(timeout_s=0.0 if len(answers) > 2 else 10.0)
            # The republished state reaches the subscriber on Zenoh's thread: wait for it
            # (a loaded machine delivered it after the undeclare), bounded.
            deadline = time.monotonic() + 10.0
            while not published and time.monotonic() < deadline:
                time.sleep(0.01)
        finally:
            qbl.undeclare()
            sub.undeclare()
    assert asked[0] == b'{"agents":[1,2]}'
    if answers[-1]:
        assert not confirmed and len(asked) == 1 and published == {2: 1}
    else:  # netem lacked agent 2's: published again, then acknowledged
        assert confirmed and len(asked) == 2 and published == {2: 1}


def test_an_agent_without_netem_leaves_at_once(scenario: Scenario) -> None:
    with peer_service(RUN, "agent", 1) as svc:
        node = AgentNode(svc, scenario, [1], "estimate", seed=1)
        assert node.confirm_final() is False  # nobody answers: nothing to wait for


@pytest.mark.parametrize("garbled", [b"not json", b"[2]"], ids=["not-json", "not-an-object"])
def test_a_garbled_answer_is_counted_and_the_agent_leaves(
    scenario: Scenario, garbled: bytes
) -> None:
    with peer_service(RUN, "agent", 1) as svc:
        node = AgentNode(svc, scenario, [1], "estimate", seed=1)
        key = keys.netem_final(RUN)
        qbl = svc.session.declare_queryable(key, lambda q: q.reply(q.key_expr, garbled))
        try:
            assert node.confirm_final() is False
        finally:
            qbl.undeclare()
        assert svc.malformed.counts[key] == 1


@pytest.mark.parametrize("done", [10, 3])
def test_the_leader_asks_for_its_last_estimates(
    scenario: Scenario, done: int, caplog: pytest.LogCaptureFixture
) -> None:
    asked: list[bytes] = []

    def on_final(query) -> None:  # type: ignore[no-untyped-def]
        asked.append(query.payload.to_bytes())
        query.reply(query.key_expr, f'{{"missing": [], "estimates_done": {done}}}'.encode())

    with peer_service(RUN, "leader", 0) as svc:
        node = LeaderNode(svc, scenario)
        qbl = svc.session.declare_queryable(keys.netem_final(RUN), on_final)
        try:
            with caplog.at_level(logging.WARNING, logger="leader"):
                node.confirm_last()
        finally:
            qbl.undeclare()
    assert asked == [b'{"estimates":true}']
    warned = [r.getMessage() for r in caplog.records if r.name == "leader"]
    assert warned == (
        [] if done == scenario.epochs else ["netem has handled estimates of 3 epochs of 10"]
    )
