"""A delivery's payloads decoded at once are each what decoding it alone gives: a message
that is not one value (two joined, or none) cannot shift the others."""

from __future__ import annotations

from formation.codec import payloads
from formation.messages import CoordinationState, DeliveredPacket

STATE = CoordinationState(run_id="r", sender="agent/2", seq=0, epoch=1, stamp_ns=0, agent=2,
                          position=[1.0, 2.0]).model_dump_json()  # fmt: skip


def _packets(*messages: str) -> list[DeliveredPacket]:
    return [DeliveredPacket(source=2, seq=0, sent_epoch=1, message=m) for m in messages]


def test_valid_payloads_are_decoded_together_with_the_models_values() -> None:
    got = payloads(CoordinationState, _packets(STATE, STATE.replace('"agent":2', '"agent":3')))
    assert [(m.agent, m.position) for m in got] == [(2, [1.0, 2.0]), (3, [1.0, 2.0])]


def test_a_message_of_two_values_or_none_is_invalid_and_the_others_stay_theirs() -> None:
    got = payloads(CoordinationState, _packets(f"{STATE},{STATE}", STATE, "", " ", STATE))
    assert [m is None for m in got] == [True, False, True, True, False]
    # joined, these make a valid array of three values for two messages
    assert [
        m is None for m in payloads(CoordinationState, _packets(f"{STATE},{STATE}", STATE))
    ] == [
        True,
        False,
    ]
