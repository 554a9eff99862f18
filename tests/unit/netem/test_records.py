"""netem's tuple-built records are exactly the wire messages the pydantic models validate."""

from __future__ import annotations

import orjson
from hypothesis import given
from hypothesis import strategies as st

from formation.messages import (
    LINK_CLASS_OF,
    CoordinationState,
    DecisionBatch,
    Delivery,
    decision_rows,
)
from netem.links.layer_stack import Outcome
from netem.proxy.records import (
    Record,
    decision_batch,
    delivery,
    delivery_head,
    delivery_of,
    packet_json,
)
from shell import MemoryBus, Service

HEADER = {"run_id": "r", "sender": "netem", "seq": 3, "epoch": 7, "stamp_ns": 11}

decisions = st.sampled_from(
    [
        Outcome(True, 0, 0.0, 1, "pass", "", ""),
        Outcome(False, 0, 0.0, 0, "drop", "gilbert_elliott", "bad"),
        Outcome(True, 2, 0.0, 1, "delayed", "", ""),
        Outcome(True, 0, 12.5, 2, "duplicate", "", "3,down"),
    ]
)
records = st.tuples(
    st.integers(0, 1000),
    st.integers(0, 1000),
    st.integers(0, 10**6),
    st.integers(0, 10**6),
    decisions,
)
phases = st.sampled_from(["state", "report", "estimate"])


def _records(phase: str, recs: list[tuple[int, int, int, int, Outcome]]) -> list[Record]:
    """Records of ``phase``'s link class (each class belongs to one phase)."""
    return [(s, t, LINK_CLASS_OF[phase], e, q, d) for s, t, e, q, d in recs]


@given(st.lists(records, max_size=20), phases)
def test_decision_batch_validates_and_keeps_every_field(
    recs: list[tuple[int, int, int, int, Outcome]], phase: str
) -> None:
    batch = DecisionBatch.model_validate_json(decision_batch(HEADER, phase, _records(phase, recs)))
    assert batch.phase == phase and batch.epoch == 7 and batch.sender == "netem"
    rows = decision_rows(batch)
    assert len(rows) == len(recs)
    for got, r in zip(rows, _records(phase, recs), strict=True):
        assert (got.source, got.target, got.link_class, got.epoch, got.seq) == r[:5]
        d = r[5]
        assert (got.verdict, got.delay_epochs, got.delay_ms, got.model, got.state) == (
            d.verdict, d.delay_epochs, d.delay_ms, d.model, d.state,
        )  # fmt: skip
    # each decision once: as many judgements as distinct decisions
    assert len(batch.judgements) == len({r[4] for r in recs})


payloads = st.one_of(
    st.builds(
        lambda k, x: (
            CoordinationState(
                run_id="r", sender="agent/1", seq=k, epoch=k, stamp_ns=1, agent=1, position=[x, -x]
            )
            .model_dump_json()
            .encode()
        ),
        st.integers(0, 99),
        st.floats(allow_nan=False, allow_infinity=False),
    ),
    st.binary(max_size=40),  # whatever a sender put on the wire: the receiver judges it
)


@given(
    st.lists(st.tuples(st.integers(0, 99), st.integers(0, 99), st.integers(0, 99),
                       st.integers(1, 2), payloads), max_size=8),
    st.lists(st.integers(0, 99), max_size=8),
    st.lists(st.integers(0, 99), max_size=4),
)  # fmt: skip
def test_delivery_validates_sorted_with_every_payload(
    packets: list[tuple[int, int, int, int, bytes]], lost: list[int], dead: list[int]
) -> None:
    raw = delivery(HEADER, 4, "state", [packet_json(*p) for p in packets], lost, dead)
    # Spliced from pre-encoded packets, byte for byte one JSON dump of the same fields.
    assert raw == orjson.dumps({**HEADER, "kind": "delivery", "receiver": 4, "phase": "state",
        "packets": [{"source": s, "seq": q, "sent_epoch": e, "copies": c,
                     "message": m.decode("utf-8", "replace")} for s, q, e, c, m in packets],
        "lost": sorted(lost), "dead": sorted(dead)})  # fmt: skip
    got = Delivery.model_validate_json(raw)
    assert got.receiver == 4 and got.phase == "state"
    assert [(p.source, p.seq, p.sent_epoch, p.copies) for p in got.packets] == [
        p[:4] for p in packets
    ]
    assert got.lost == sorted(lost) and got.dead == sorted(dead)
    for p, sent in zip(got.packets, packets, strict=True):
        try:
            want = CoordinationState.model_validate_json(sent[4])
        except ValueError:
            continue  # not a message: the receiver counts it as malformed
        assert CoordinationState.model_validate_json(p.message) == want  # through unchanged


def _reference_batch(header: dict[str, object], phase: str, recs: list[Record]) -> bytes:
    """The batch as one orjson dump of plain dicts: what the spliced encoding must equal."""
    judged = list(dict.fromkeys(r[5] for r in recs))
    return orjson.dumps({**header, "kind": "decisions", "phase": phase, "judgements": [
        {"verdict": d.verdict, "delay_epochs": d.delay_epochs, "delay_ms": float(d.delay_ms),
         "model": d.model, "state": d.state} for d in judged
    ], "records": {"source": [r[0] for r in recs], "target": [r[1] for r in recs],
                   "epoch": [r[3] for r in recs], "seq": [r[4] for r in recs],
                   "judgement": [judged.index(r[5]) for r in recs]}})  # fmt: skip


@given(st.lists(records, max_size=20), phases)
def test_decision_batch_is_byte_for_byte_one_json_dump(
    recs: list[tuple[int, int, int, int, Outcome]], phase: str
) -> None:
    batch = _records(phase, recs)
    assert decision_batch(HEADER, phase, batch) == _reference_batch(HEADER, phase, batch)


@given(
    run_id=st.text(min_size=1, max_size=12),
    seq=st.integers(0, 10**9),
    epoch=st.integers(-1, 10**6),
    lost=st.lists(st.integers(1, 50), max_size=4),
)
def test_the_outbox_s_spliced_delivery_is_the_one_built_from_the_header(
    run_id: str, seq: int, epoch: int, lost: list[int]
) -> None:
    service = Service(MemoryBus(), run_id, "netem", 0)
    header = {"run_id": run_id, "sender": service.name, "seq": seq, "epoch": epoch, "stamp_ns": 5}
    packets = [packet_json(2, 4, epoch, 1, b'{"agent":2}')]
    head = delivery_head(service.header_format(), 9, "state") % (seq, epoch, 5)
    want = delivery(header, 9, "state", packets, lost, [3])
    assert delivery_of(head, packets, lost, [3]) == want
    Delivery.model_validate_json(want)
