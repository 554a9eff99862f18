"""A delivery's payloads are each what decoding it alone gives: a message that is not one
value (two joined, or none, or a part of one) cannot shift the others."""

from __future__ import annotations

from formation.codec import payloads
from formation.messages import CoordinationState, DeliveredPacket

STATE = CoordinationState(run_id="r", sender="agent/2", seq=0, epoch=1, stamp_ns=0, agent=2,
                          position=[1.0, 2.0]).model_dump_json()  # fmt: skip
OTHER = STATE.replace('"agent":2', '"agent":3').replace("agent/2", "agent/3")


def _packets(*messages: str) -> list[DeliveredPacket]:
    return [DeliveredPacket(source=2, seq=0, sent_epoch=1, message=m) for m in messages]


def test_valid_payloads_are_decoded_with_the_models_values() -> None:
    got = payloads(CoordinationState, _packets(STATE, OTHER))
    assert [(m.agent, m.position) for m in got] == [(2, [1.0, 2.0]), (3, [1.0, 2.0])]


def test_a_message_of_two_values_or_none_is_invalid_and_the_others_stay_theirs() -> None:
    got = payloads(CoordinationState, _packets(f"{STATE},{STATE}", STATE, "", " ", STATE))
    assert [m is None for m in got] == [True, False, True, True, False]


def test_malformed_messages_around_a_valid_one_cannot_take_its_slot() -> None:
    """Joined into one array these four are four valid states, the second of them the
    first message's: a decoder that joins them gives agent 3's slot agent 2's state."""
    cut = STATE.index(',"position"')  # the joining comma stands for the one cut out
    got = payloads(
        CoordinationState, _packets(f"{STATE},{STATE}", OTHER, STATE[:cut], STATE[cut + 1 :])
    )
    assert got[0] is None and got[2] is None and got[3] is None
    assert (got[1].agent, got[1].sender) == (3, "agent/3")
