"""A pool's states in one bundle, read from a recording: the trust gate checks each part as if
it came alone on its agent's key, counts and leaves out a forged or malformed part and keeps
the others; the bulk reader takes a chunk's bundles as the gate does, or vouches for nothing."""

from __future__ import annotations

from typing import Any

import numpy as np

from formation import keys
from formation.codec import encode
from formation.messages import Bundle, CoordinationState
from recorder.reading.state_batch import judge_bundles
from recorder.reading.trust import CONFLICT, FORGED, INVALID, Gate

KEY = keys.pool_states("r", 2)


def part(agent: int, epoch: int = 3, sender: str = "pool/2", x: float = 0.0) -> dict[str, Any]:
    state = CoordinationState(run_id="r", sender=sender, seq=epoch, epoch=epoch, stamp_ns=1,
                              agent=agent, position=[x, float(agent)], substituted=[])  # fmt: skip
    return {"agent": agent, "seq": epoch, "message": state.model_dump_json()}


def bundle(*parts: dict[str, Any], epoch: int = 3, sender: str = "pool/2") -> bytes:
    return encode(Bundle(run_id="r", sender=sender, seq=epoch, epoch=epoch, stamp_ns=1,
                         phase="state", parts=parts))  # fmt: skip


def agents(checked: Any) -> list[int]:
    return [s.agent for s in checked.states]


def test_each_part_is_checked_as_if_it_came_alone_and_a_bad_one_left_out(paper: Any) -> None:
    gate = Gate(paper)
    assert agents(gate.check(KEY, bundle(part(2), part(3)))) == [2, 3]
    assert gate.check(KEY, bundle(part(2, epoch=4), epoch=4, sender="pool/1")) is None
    mixed = bundle(
        part(2, epoch=5),
        part(1, epoch=5, sender="pool/1"),  # not this pool's agent
        {**part(3, epoch=5), "agent": 4},  # agent 3's state for agent 4
        part(3, epoch=6),  # another epoch's
        {**part(4, epoch=5), "message": "{"},
        part(5, epoch=5, x=float("nan")),
        epoch=5,
    )
    assert agents(gate.check(KEY, mixed)) == [2]
    own = CoordinationState(run_id="r", sender="agent/3", seq=7, epoch=7, stamp_ns=1, agent=3,
                            position=[1.0, 3.0], substituted=[])  # fmt: skip
    assert gate.check(keys.agent_state("r", 3), encode(own)) is not None
    assert agents(gate.check(KEY, bundle(part(2, epoch=7), part(3, epoch=7), epoch=7))) == [2]
    assert gate.skipped.by_reason() == {FORGED: 4, INVALID: 2, CONFLICT: 1}
    assert {topic for topic, _ in gate.skipped.counts} == {KEY}


def test_the_bulk_reader_takes_a_chunks_bundles_as_the_gate_does(paper: Any) -> None:
    datas = [bundle(part(2, epoch=k, x=k), part(3, epoch=k), epoch=k) for k in range(4)]
    bulk = Gate(paper, plain_bulk=True)
    block = judge_bundles(bulk, [KEY] * len(datas), datas)
    one_by_one = Gate(paper)
    states = [s for data in datas for s in one_by_one.check(KEY, data).states]  # type: ignore[union-attr]
    assert block is not None
    assert block.agent.tolist() == [s.agent for s in states]
    assert block.epoch.tolist() == [s.epoch for s in states]
    np.testing.assert_array_equal(block.position, [s.position for s in states])
    assert bulk.seen == one_by_one.seen  # each part remembered under its agent's key
    for forged in (
        bundle(part(2, epoch=5), {**part(3, epoch=5), "seq": 9}, epoch=5),  # not the part's seq
        bundle(part(2, epoch=6), part(3, epoch=5), epoch=6),  # another epoch's part
        bundle(part(1, epoch=7), epoch=7),  # not the pool's agent
        bundle(part(2, epoch=8), epoch=8, sender="pool/1"),
    ):
        gate = Gate(paper, plain_bulk=True)
        assert judge_bundles(gate, [KEY], [forged]) is None
        assert not gate.passed and not gate.seen and not gate.skipped.total
