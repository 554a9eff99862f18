"""An agent's orjson-built messages are exactly what the wire models validate."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from agent.outgoing import report_message, state_message
from formation.messages import CoordinationState, TokenReport

HEAD = {"run_id": "r", "sender": "agent/3", "seq": 5, "epoch": 9, "stamp_ns": 17}
floats = st.floats(allow_nan=False, allow_infinity=False)
vectors = st.lists(floats, min_size=2, max_size=3)


@given(vectors, st.lists(st.tuples(st.integers(1, 99), vectors, st.booleans()), max_size=4))
def test_state_message_validates_with_every_field(
    position: list[float], substituted: list[tuple[int, list[float], bool]]
) -> None:
    msg = CoordinationState.model_validate_json(state_message(HEAD, 3, position, substituted))
    assert (msg.run_id, msg.sender, msg.seq, msg.epoch, msg.stamp_ns) == tuple(HEAD.values())
    assert msg.agent == 3 and msg.position == position and msg.velocity is None
    assert [(s.neighbour, s.value, s.fallback) for s in msg.substituted] == substituted


@given(st.lists(st.tuples(st.integers(1, 99), st.booleans(), st.none() | vectors), max_size=6))
def test_report_message_validates_with_every_field(
    report: list[tuple[int, bool, list[float] | None]],
) -> None:
    msg = TokenReport.model_validate_json(report_message(HEAD, 3, report))
    assert msg.agent == 3 and msg.epoch == 9
    assert [(m.neighbour, m.token, m.z) for m in msg.measurements] == [
        (j, int(t), z) for j, t, z in report
    ]
