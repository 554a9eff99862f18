"""A message read in bulk (:meth:`Malformed.read`, :meth:`Malformed.decode_packets`) has the
model's answer: its values where the model takes it, None and counted where it refuses."""

from __future__ import annotations

from typing import Any

import msgspec
import orjson
import pytest
from pydantic import BaseModel

from formation.codec import Malformed
from formation.messages import (
    AgentEstimate,
    CoordinationState,
    DeliveredPacket,
    Delivery,
    TokenReport,
)
from formation.structs import decoder_of

HEAD = {"run_id": "r", "sender": "agent/1", "seq": 3, "epoch": 2, "stamp_ns": 5}
VALID: list[tuple[type[BaseModel], dict[str, Any]]] = [
    (CoordinationState, {**HEAD, "kind": "state", "agent": 1, "position": [0.1, 2]}),
    (
        TokenReport,
        {
            **HEAD,
            "agent": 1,
            "measurements": [{"neighbour": 2, "token": 1, "z": [1.5, -0.25]}, {"neighbour": 3, "token": 0}],
        },
    ),
    (
        AgentEstimate,
        {**HEAD, "agent": 1, "neighbours": [2, 3], "positions": [[1.0, 2.0], None], "v_ref": [0, 0.5]},
    ),
    (
        Delivery,
        {
            **HEAD,
            "receiver": 1,
            "phase": "state",
            "packets": [{"source": 2, "seq": 0, "sent_epoch": 2, "message": "{}"}],
            "lost": [3],
        },
    ),
]  # fmt: skip


def _values(msg: Any) -> Any:
    if isinstance(msg, BaseModel):
        return {k: _values(v) for k, v in msg}
    if isinstance(msg, msgspec.Struct):
        return {k: _values(getattr(msg, k)) for k in msg.__struct_fields__}
    if isinstance(msg, list | tuple):
        return [_values(v) for v in msg]
    return msg


@pytest.mark.parametrize(("model", "fields"), VALID, ids=lambda x: getattr(x, "__name__", ""))
def test_a_valid_message_reads_as_the_model_reads_it(
    model: type[BaseModel], fields: dict[str, Any]
) -> None:
    malformed = Malformed()
    payload = orjson.dumps(fields)
    got = malformed.read("k", payload, model)
    assert isinstance(got, msgspec.Struct)  # the shortcut taken
    assert _values(got) == _values(model.model_validate_json(payload))
    assert not malformed.counts


def test_what_msgspec_refuses_is_left_to_the_model() -> None:
    malformed = Malformed()
    fields = {**HEAD, "seq": 3.0, "kind": "state", "agent": 1, "position": [0.0, 0.0]}
    got = malformed.read("k", orjson.dumps(fields), CoordinationState)
    assert isinstance(got, CoordinationState) and got.seq == 3  # pydantic takes 3.0 for an int
    assert not malformed.counts


@pytest.mark.parametrize(
    "change",
    [{"seq": -1}, {"extra": 1}, {"position": "x"}, {"agent": None}, {"kind": "report"}],
)
def test_an_invalid_message_is_none_and_counted(change: dict[str, Any]) -> None:
    malformed = Malformed()
    fields = {**HEAD, "kind": "state", "agent": 1, "position": [0.0, 0.0], **change}
    assert malformed.read("k", orjson.dumps(fields), CoordinationState) is None
    assert malformed.read("k", b"{not json", CoordinationState) is None
    assert malformed.counts["k"] == 2


def test_a_delivery_s_packets_are_read_one_by_one() -> None:
    malformed = Malformed()
    good = orjson.dumps({**HEAD, "kind": "state", "agent": 2, "position": [1.0, 2.0]}).decode()
    packets = [
        DeliveredPacket(source=2, seq=0, sent_epoch=2, message=good),
        DeliveredPacket(source=3, seq=0, sent_epoch=2, message='{"agent": 3}'),
        DeliveredPacket(source=4, seq=0, sent_epoch=2, message=good),  # agent 2's, from 4
    ]
    got = list(
        malformed.decode_packets(
            packets,
            CoordinationState,
            lambda p: f"link/{p.source}",
            lambda p, m: m.agent == p.source,
        )
    )
    assert [(p.source, list(m.position)) for p, m in got] == [(2, [1.0, 2.0])]
    assert malformed.counts == {"link/3": 1, "link/4": 1}


def test_a_model_s_decoder_is_made_once() -> None:
    assert decoder_of(Delivery) is decoder_of(Delivery)
    assert decoder_of(Delivery) is not decoder_of(CoordinationState)
