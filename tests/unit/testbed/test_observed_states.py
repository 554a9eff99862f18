"""The launcher's observer reads a pool's state bundle whole, as arrays, only when every part is
plainly a state of its own agent; its rows are what reading the parts one by one gives."""

from __future__ import annotations

from typing import Any

import orjson
import pytest

from testbed.runtime.observed_states import Bounds, read_bundle, read_parts, read_state

BOUNDS = Bounds(epochs=10, n=8, dimension=2)


def _state(agent: int, epoch: int = 3, seq: int = 3, **changed: Any) -> dict[str, Any]:
    """A state as a pool's agent sends it (agent.node.state_message's fields)."""
    msg = {
        "run_id": "r",
        "sender": "pool/5",
        "seq": seq,
        "epoch": epoch,
        "stamp_ns": 1,
        "kind": "state",
        "agent": agent,
        "position": [0.1 * agent, -2.5 + agent / 3],
        "velocity": None,
        "substituted": [],
    }
    return {**msg, **changed}


def _bundle(states: list[dict[str, Any]], owners: list[int] | None = None) -> bytes:
    owners = owners or [s["agent"] for s in states]
    parts = [
        {"agent": a, "seq": s["seq"], "message": orjson.dumps(s).decode()}
        for a, s in zip(owners, states, strict=True)
    ]
    head = {"run_id": "r", "sender": "pool/5", "seq": 3, "epoch": 3, "stamp_ns": 1}
    return orjson.dumps({**head, "kind": "bundle", "phase": "state", "parts": parts})


def test_the_rows_of_a_bundle_are_its_parts_read_one_by_one() -> None:
    subs = [
        {"neighbour": 2, "value": [1.0, 2.25], "fallback": True},
        {"neighbour": 7, "value": [3, -1e-3], "fallback": False},
    ]
    states = [_state(5, seq=0), _state(6, substituted=subs), _state(8, epoch=4, seq=4)]
    payload = _bundle(states)
    rows = read_bundle(payload, 5, BOUNDS)
    assert rows is not None
    parts = read_parts(payload, 5)
    assert parts is not None
    one_by_one = [read_state(message, str(i), BOUNDS) for i, message in parts]
    for r, alone in enumerate(one_by_one):
        assert alone is not None
        assert (rows.epoch[r], rows.agent[r], rows.seq[r]) == alone[:3]
        assert rows.position[r].tolist() == alone.position  # the same doubles, to the bit
        assert rows.substituted[r] == alone.substituted
        assert rows.fell_back[r] == alone.fell_back
    assert rows.fell_back.tolist() == [0, 1, 0]


@pytest.mark.parametrize(
    ("states", "owners"),
    [
        ([_state(5), _state(6, position=[1.0])], None),  # a position of the wrong dimension
        ([_state(5), _state(6, epoch=11)], None),  # past the run's last epoch
        ([_state(5), _state(9)], None),  # no such agent
        ([_state(5), _state(6)], [5, 7]),  # a part standing for another agent
        ([_state(4), _state(6)], None),  # an agent before the pool's first
        ([_state(5), _state(5, epoch=4, seq=4)], None),  # an agent twice
        ([_state(5), _state(6, epoch=3.0)], None),  # an epoch as a float (read alone: 3)
        ([_state(5), _state(6, substituted=None)], None),  # no substitutes
    ],
)
def test_a_bundle_with_any_doubtful_part_is_left_to_be_read_part_by_part(
    states: list[dict[str, Any]], owners: list[int] | None
) -> None:
    assert read_bundle(_bundle(states, owners), 5, BOUNDS) is None


@pytest.mark.parametrize(
    "payload", [b"not json", b'{"parts": 3}', b"[]", _bundle([])[:-10], b'{"parts": []}']
)
def test_a_payload_that_is_no_bundle_is_none_and_never_raises(payload: bytes) -> None:
    assert read_bundle(payload, 5, BOUNDS) is None


def test_a_part_inside_a_bundle_cannot_spill_into_the_next() -> None:
    """Two parts, neither a state alone, whose texts joined by a comma would be two good states."""
    good = orjson.dumps(_state(5)).decode()
    opened = '{"epoch":3,"agent":6,"seq":3,"position":[0.6,-0.5],"substituted":[],"run_id":"'
    parts = [
        {"agent": 5, "seq": 3, "message": f"{good},{opened}"},
        {"agent": 6, "seq": 3, "message": '"}'},
    ]
    payload = orjson.dumps({"parts": parts})
    joined = "[" + ",".join(p["message"] for p in parts) + "]"
    assert [s["agent"] for s in orjson.loads(joined)] == [5, 6]  # what a joined read would keep
    assert read_bundle(payload, 5, BOUNDS) is None
    assert [read_state(m, str(i), BOUNDS) for i, m in read_parts(payload, 5) or []] == [None, None]
