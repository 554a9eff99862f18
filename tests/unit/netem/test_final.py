"""A sender leaves only once netem has its last messages: netem's ``netem/final`` queryable,
driven through its node on the in-memory bus."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

from formation import keys
from formation.codec import attachment, encode, now_ns
from formation.messages import CoordinationState
from formation.scenario import Scenario
from netem.node import FINAL_WAIT_S, NetemNode
from shell import MemoryBus, Service

ROOT = Path(__file__).resolve().parents[3]
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
    svc = Service(MemoryBus(), RUN, "netem", 0, start_timeout_s=5)
    node = NetemNode(svc, scenario, seed=1, wait_for_recorder=False)
    assert svc.ask(final_key, {"agents": [1, 2]}) == {"missing": [1, 2], "estimates_done": 0}
    node.handle_packet(*_final_state(1, scenario.epochs))
    assert svc.ask(final_key, {"agents": [1, 2]})["missing"] == [2]
    # A final state that arrives while the query waits is counted before the answer.
    late = threading.Timer(FINAL_WAIT_S / 5, node.handle_packet, _final_state(2, scenario.epochs))
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
    svc.close()
