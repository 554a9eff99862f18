"""netem's tuple-built records are exactly the wire messages the pydantic models validate."""

from __future__ import annotations

import orjson
from hypothesis import given
from hypothesis import strategies as st

from formation.messages import DecisionBatch, EpochClose
from netem.records import Forwarded, Record, decision_batch, epoch_close
from netem.stack import Decision

HEADER = {"run_id": "r", "sender": "netem", "seq": 3, "epoch": 7, "stamp_ns": 11}

decisions = st.sampled_from(
    [
        Decision(True, 0, 0.0, 1, "pass", "", ""),
        Decision(False, 0, 0.0, 0, "drop", "gilbert_elliott", "bad"),
        Decision(True, 2, 0.0, 1, "delayed", "", ""),
        Decision(True, 0, 12.5, 2, "duplicate", "", "3,down"),
    ]
)
records = st.tuples(
    st.integers(0, 1000),
    st.integers(0, 1000),
    st.sampled_from(["formation", "report", "estimate"]),
    st.integers(0, 10**6),
    st.integers(0, 10**6),
    decisions,
)


@given(st.lists(records, max_size=20), st.sampled_from(["state", "report", "estimate"]))
def test_decision_batch_validates_and_keeps_every_field(recs: list[Record], phase: str) -> None:
    batch = DecisionBatch.model_validate_json(decision_batch(HEADER, phase, recs))
    assert batch.phase == phase and batch.epoch == 7 and batch.sender == "netem"
    assert len(batch.decisions) == len(recs)
    for got, r in zip(batch.decisions, recs, strict=True):
        assert (got.source, got.target, got.link_class, got.epoch, got.seq) == r[:5]
        d = r[5]
        assert (got.verdict, got.delay_epochs, got.delay_ms, got.model, got.state) == (
            d.verdict, d.delay_epochs, d.delay_ms, d.model, d.state,
        )  # fmt: skip


@given(
    st.lists(st.tuples(st.integers(0, 99), st.integers(0, 99), st.integers(0, 99),
                       st.integers(1, 2)), max_size=8),
    st.lists(st.integers(0, 99), max_size=8),
    st.lists(st.integers(0, 99), max_size=4),
)  # fmt: skip
def test_epoch_close_validates_sorted(
    delivered: list[Forwarded], lost: list[int], dead: list[int]
) -> None:
    close = EpochClose.model_validate_json(epoch_close(HEADER, 4, "state", delivered, lost, dead))
    assert close.receiver == 4 and close.phase == "state"
    assert [(d.source, d.seq, d.sent_epoch, d.copies) for d in close.delivered] == delivered
    assert close.lost == sorted(lost) and close.dead == sorted(dead)


def _reference_batch(header: dict[str, object], phase: str, recs: list[Record]) -> bytes:
    """The batch as one orjson dump of plain dicts: what the spliced encoding must equal."""
    return orjson.dumps({**header, "kind": "decisions", "phase": phase, "decisions": [
        {"source": s, "target": t, "link_class": c, "epoch": e, "seq": q, "verdict": d.verdict,
         "delay_epochs": d.delay_epochs, "delay_ms": float(d.delay_ms), "model": d.model,
         "state": d.state}
        for s, t, c, e, q, d in recs
    ]})  # fmt: skip


@given(st.lists(records, max_size=20), st.sampled_from(["state", "report", "estimate"]))
def test_decision_batch_is_byte_for_byte_one_json_dump(recs: list[Record], phase: str) -> None:
    assert decision_batch(HEADER, phase, recs) == _reference_batch(HEADER, phase, recs)
