"""A phase's deliveries as the runner's arrays: the packets of a link, the last one counts (a
delayed one only if newer than what is held), and an agent's estimate is read as a mapping of
its neighbours to their positions, the last of a neighbour named twice counting."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from agent.incoming import delivered_estimates
from agent.runner import AgentRunner
from formation.messages import DeliveredPacket
from formation.scenario import Scenario
from shell import Columns

ROOT = Path(__file__).resolve().parents[3]
PAPER = Scenario.from_file(ROOT / "scenarios/paper.toml")
EPOCH = 3
packets = st.lists(
    st.tuples(
        st.integers(1, 5),  # receiver
        st.integers(0, 6),  # source (0 and 6 are no agent's in-neighbour)
        st.integers(EPOCH - 2, EPOCH + 1),  # sent epoch: delayed, now, or ahead
        st.tuples(st.floats(-9, 9), st.floats(-9, 9)),
    ),
    max_size=30,
)


def _runner() -> AgentRunner:
    runner = AgentRunner(PAPER, [1, 2, 3, 4, 5], "hold", seed=1)
    runner.epoch = EPOCH
    return runner


@settings(max_examples=60, deadline=None)
@given(packets)
def test_each_link_takes_its_last_packet_of_the_epoch_and_holds_its_newest_delayed_one(
    given_packets: list[tuple[int, int, int, tuple[float, float]]],
) -> None:
    runner = _runner()
    held = runner.memory
    arrived: dict[int, tuple[float, float]] = {}
    newest: dict[int, tuple[int, tuple[float, float]]] = {}  # link → (sent epoch, x_j)
    links = list(zip(runner.links.receiver.tolist(), runner.links.sender.tolist(), strict=True))
    for i, j, sent, x in given_packets:  # the rule, packet by packet in delivery order
        if (i, j) not in links:
            continue
        link = links.index((i, j))
        if sent == EPOCH:
            arrived[link] = x
        elif sent < EPOCH and sent >= newest.get(link, (-1, x))[0]:
            newest[link] = (sent, x)
    columns = np.array([(i, j, sent) for i, j, sent, _ in given_packets], dtype=np.int64)
    columns = columns.reshape(-1, 3)
    positions = np.array([x for *_, x in given_packets], dtype=float).reshape(-1, 2)
    runner.receive(columns[:, 0], columns[:, 1], columns[:, 2], positions)
    assert set(np.flatnonzero(runner.arrived).tolist()) == set(arrived)
    for link, x in arrived.items():
        assert tuple(runner._received[link]) == x
    for link in range(len(links)):
        sent, x = newest.get(link, (-1, (0.0, 0.0)))
        if sent > held.last_epoch[link]:  # a delayed packet newer than the held value
            assert runner.memory.last_epoch[link] == sent
            assert tuple(runner.memory.last[link]) == x


estimates = st.lists(
    st.tuples(
        st.lists(st.integers(0, 7), max_size=5),  # neighbours, some named twice
        st.lists(st.none() | st.tuples(st.floats(-9, 9), st.floats(-9, 9)), max_size=5),
        st.tuples(st.floats(-1, 1), st.floats(-1, 1)),  # v_ref
    ),
    min_size=5,
    max_size=5,
)


class _Estimate:
    """An agent's decoded estimate: the fields the runner reads."""

    def __init__(self, agent: int, neighbours: list[int], positions: list[Any], v_ref: Any):
        self.agent, self.neighbours = agent, neighbours
        self.positions = [None if p is None else list(p) for p in positions]
        self.v_ref = list(v_ref)


@settings(max_examples=60, deadline=None)
@given(estimates, st.lists(st.booleans(), min_size=5, max_size=5))
def test_an_estimate_is_read_as_a_mapping_of_neighbours_to_positions(
    given_estimates: list[tuple[list[int], list[Any], Any]], came: list[bool]
) -> None:
    runner = _runner()
    ids = [i for i, c in zip(runner.ids, came, strict=True) if c]
    messages = [_Estimate(i, *given_estimates[i - 1]) for i in ids]
    packets = [DeliveredPacket(source=0, seq=0, sent_epoch=EPOCH, message="") for _ in ids]
    columns = Columns(
        np.array(ids, dtype=np.int64),
        np.arange(len(ids), dtype=np.int64),
        packets,
        messages,
        np.zeros(len(ids), dtype=np.int64),
        np.full(len(ids), EPOCH, dtype=np.int64),
    )
    v_ref, has_v_ref, estimate, has_estimate = delivered_estimates(columns, runner)
    assert has_v_ref.tolist() == came
    for m in messages:
        assert v_ref[runner.row[m.agent]].tolist() == m.v_ref
    pairs = zip(runner.links.receiver.tolist(), runner.links.sender.tolist(), strict=True)
    for link, (i, j) in enumerate(pairs):  # the rule: dict(zip(neighbours, positions))
        m = next((m for m in messages if m.agent == i), None)
        value = None if m is None else dict(zip(m.neighbours, m.positions, strict=False)).get(j)
        assert has_estimate[link] == (value is not None)
        if value is not None:
            assert estimate[link].tolist() == value
