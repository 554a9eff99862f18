"""netem's decision batches as columns through the trust gate: a good batch's table is its
rows', and a malformed one is skipped with the column, record or value at fault named, on
the model's path and the bulk path alike."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest

from formation import keys
from formation.messages import Decision, DecisionBatch, decision_rows
from formation.scenario import Scenario
from recorder.reading.collected import Collected
from recorder.reading.trust import FORGED, INVALID, OUT_OF_RANGE, Gate

RUN = "r"
TOPIC = keys.netem_decision(RUN)


def _batch(**change: Any) -> dict[str, Any]:
    """A state batch of epoch 3 on links 1→2 (passed, delayed) and 2→1 (dropped)."""
    body: dict[str, Any] = {
        "run_id": RUN, "sender": "netem", "seq": 0, "epoch": 3, "stamp_ns": 1,
        "kind": "decisions", "phase": "state",
        "judgements": [{"verdict": "pass"}, {"verdict": "drop", "model": "bernoulli"},
                       {"verdict": "delayed", "delay_epochs": 2, "queue": "radio 1",
                        "queue_depth": 4, "sojourn_ms": 1.5}],
        "records": {"source": [1, 2, 1], "target": [2, 1, 2], "epoch": [3, 3, 3],
                    "seq": [3, 3, 4], "judgement": [0, 1, 2]},
    }  # fmt: skip
    for name, value in change.items():
        if name in body["records"]:
            body["records"][name] = value
        else:
            body[name] = value
    return body


def _skip(paper: Scenario, body: dict[str, Any]) -> tuple[str, str]:
    """The reason and detail both gates give ``body``, which neither passes."""
    got = set()
    for plain_bulk in (False, True):
        gate = Gate(paper, plain_bulk=plain_bulk)
        assert gate.check(TOPIC, json.dumps(body).encode(), "decision") is None
        ((_, reason, detail),) = gate.skipped.examples
        got.add((reason, detail))
    (one,) = got
    return one


def _table(batches: list[Any]) -> Any:
    """The decisions table the reader makes of trusted ``batches`` (:class:`Collected`)."""
    got = Collected(bulk=True, d=2)
    for batch in batches:
        got.add("decision", batch)
    return got.decisions_of_run()


@pytest.mark.parametrize("plain_bulk", [False, True])
def test_a_batch_s_columns_are_its_rows(paper: Scenario, plain_bulk: bool) -> None:
    gate = Gate(paper, plain_bulk=plain_bulk)
    first = gate.check(TOPIC, json.dumps(_batch()).encode(), "decision")
    report = _batch(phase="report", source=[1, 2, 3], target=[0, 0, 0], judgement=[2, 2, 1])
    second = gate.check(TOPIC, json.dumps(report).encode(), "decision")
    assert first is not None and second is not None and not gate.skipped.total
    rows = decision_rows(first) + decision_rows(second)  # type: ignore[arg-type]
    assert rows[2] == Decision(source=1, target=2, link_class="formation", epoch=3, seq=4,
                               verdict="delayed", delay_epochs=2, queue="radio 1",
                               queue_depth=4, sojourn_ms=1.5)  # fmt: skip
    table = _table([first, second])
    for name in ("source", "target", "epoch", "seq", "verdict", "delay_epochs", "model"):
        assert getattr(table, name).tolist() == [getattr(r, name) for r in rows], name
    assert table.phase.tolist() == ["state"] * 3 + ["report"] * 3
    assert table.link_class.tolist() == ["formation"] * 3 + ["report"] * 3
    assert table.queue.tolist() == [None, None, "radio 1", "radio 1", "radio 1", None]
    assert table.queue_depth.tolist() == [-1, -1, 4, 4, 4, -1]
    np.testing.assert_array_equal(table.sojourn_ms, [np.nan, np.nan, 1.5, 1.5, 1.5, np.nan])


def test_of_rows_keeps_each_judgement_once() -> None:
    rows = [
        Decision(source=1, target=2, link_class="formation", epoch=k, seq=k, verdict="drop")
        for k in range(5)
    ]
    head = {"run_id": RUN, "sender": "netem", "seq": 0, "epoch": 4, "stamp_ns": 1}
    batch = DecisionBatch.of_rows(phase="state", decisions=rows, **head)
    assert len(batch.judgements) == 1 and batch.records.judgement == [0] * 5
    assert decision_rows(batch) == rows


def test_columns_of_unequal_lengths_are_named(paper: Scenario) -> None:
    assert _skip(paper, _batch(epoch=[3, 3])) == (
        INVALID,
        "decision columns of unequal lengths: source 3, target 3, epoch 2, seq 3, judgement 3",
    )


@pytest.mark.parametrize("index", [3, -1])
def test_a_judgement_the_batch_lacks_is_named(paper: Scenario, index: int) -> None:
    assert _skip(paper, _batch(judgement=[0, index, 1])) == (
        INVALID,
        f"record 1: judgement {index}, but the batch has 3 judgements",
    )


@pytest.mark.parametrize(
    ("change", "detail"),
    [
        ({"target": [2, 1, 5]}, "record 2: no formation link 1->5"),
        ({"source": [1, 9, 1]}, "record 1: endpoint 9 not in 0..5"),
        ({"epoch": [3, 50, 3]}, "record 1: epoch 50 not in 0..49"),
        ({"phase": "report"}, "record 0: no report link 1->2"),
        ({"phase": "estimate"}, "record 0: no estimate link 1->2"),
    ],
)
def test_a_record_off_the_scenario_is_named(
    paper: Scenario, change: dict[str, Any], detail: str
) -> None:
    assert _skip(paper, _batch(**change)) == (OUT_OF_RANGE, detail)


def test_a_batch_not_from_netem_is_forged(paper: Scenario) -> None:
    assert _skip(paper, _batch(sender="agent/1")) == (
        FORGED,
        "sender 'agent/1' on a key of 'netem'",
    )


def test_a_bad_value_is_invalid(paper: Scenario) -> None:
    reason, detail = _skip(paper, _batch(judgements=[{"verdict": "lost"}]))
    assert reason == INVALID and detail.startswith("DecisionBatch:")


def _rows_batch(sender: str = "netem", link_class: str = "formation") -> bytes:
    """A batch as recordings made before the columns hold it: a list of records."""
    body = {
        "run_id": RUN, "sender": sender, "seq": 0, "epoch": 3, "stamp_ns": 1,
        "kind": "decisions", "phase": "state",
        "decisions": [
            {"source": 1, "target": 2, "link_class": link_class, "epoch": 3, "seq": 3,
             "verdict": "pass"},
            {"source": 2, "target": 1, "link_class": link_class, "epoch": 3, "seq": 3,
             "verdict": "drop", "model": "bernoulli"},
        ],
    }  # fmt: skip
    return json.dumps(body).encode()


@pytest.mark.parametrize("plain_bulk", [False, True])
def test_an_older_recording_s_rows_are_read_as_columns(paper: Scenario, plain_bulk: bool) -> None:
    gate = Gate(paper, plain_bulk=plain_bulk)
    batch = gate.check(TOPIC, _rows_batch(), "decision")
    assert isinstance(batch, DecisionBatch) and not gate.skipped.total
    assert _table([batch]).verdict.tolist() == ["pass", "drop"]
    assert [(d.source, d.target, d.model) for d in decision_rows(batch)] == [
        (1, 2, ""),
        (2, 1, "bernoulli"),
    ]
    for data, reason in [
        (_rows_batch(sender="agent/1"), FORGED),
        (_rows_batch(link_class="report"), INVALID),  # not its phase's links
    ]:
        assert gate.check(TOPIC, data, "decision") is None
        assert gate.skipped.by_reason()[reason] == 1
