"""The launcher's observer counts a decision batch's drops on arrival from its judgement column
and reads its records only when asked, as they were; a batch that does not fit is None."""

from __future__ import annotations

from typing import Any

import orjson
import pytest

from testbed.runtime.observed_decisions import read_batch


def _batch(**records: list[Any]) -> dict[str, Any]:
    columns = {
        "source": [1, 2, 3],
        "target": [2, 1, 1000],
        "epoch": [7, 7, 8],
        "seq": [7, 7, 8],
        "judgement": [0, 1, 1],
    }
    judgements = [
        {"verdict": "pass", "delay_epochs": 0, "model": "", "state": ""},
        {"verdict": "drop", "model": "bernoulli"},
    ]
    return {
        "run_id": "r",
        "sender": "netem",
        "seq": 1,
        "epoch": 8,
        "stamp_ns": 1,
        "kind": "decisions",
        "phase": "state",
        "judgements": judgements,
        "records": {**columns, **records},
    }


def test_drops_come_from_the_judgement_column_and_the_records_as_they_were() -> None:
    batch = read_batch(orjson.dumps(_batch()))
    assert batch is not None
    assert batch.drops == 2 and batch.link_class == "formation"
    assert batch.judged == [("pass", ""), ("drop", "bernoulli")]
    assert batch.records() == [(1, 2, 7, 7, 0), (2, 1, 7, 7, 1), (3, 1000, 8, 8, 1)]


@pytest.mark.parametrize(
    "changed",
    [
        {"seq": [7, 7]},  # a column shorter than the others
        {"judgement": [0, 2, 1]},  # past the batch's judgements
        {"judgement": [0, -1, 1]},
        {"judgement": [0, 1.0, 1]},
    ],
)
def test_a_batch_whose_columns_do_not_fit_is_none(changed: dict[str, Any]) -> None:
    assert read_batch(orjson.dumps(_batch(**changed))) is None


@pytest.mark.parametrize("payload", [b"{", b"[]", b'{"phase": "sideways"}'])
def test_a_payload_that_is_no_batch_is_none(payload: bytes) -> None:
    assert read_batch(payload) is None


def test_a_column_of_other_values_is_kept_as_they_were_and_counted_by_its_length() -> None:
    """A column that is not plainly integers is read whole, as a reader of one record takes it."""
    batch = read_batch(orjson.dumps(_batch(source=[1, [2], 3])))
    assert batch is not None and batch.records()[1] == ([2], 1, 7, 7, 1)
    nested = read_batch(orjson.dumps(_batch(source=[1, [2, 3]])))  # 2 values, 3 by its commas
    assert nested is None


def test_integers_past_64_bits_are_read_as_they_are() -> None:
    big = 2**70
    payload = orjson.dumps(_batch()).replace(b'"epoch":[7,7,8]', f'"epoch":[7,7,{big}]'.encode())
    batch = read_batch(payload)
    assert batch is not None and batch.records()[2] == (3, 1000, big, 8, 1)


def test_a_batch_spaced_out_is_read_the_same() -> None:
    spaced = orjson.dumps(_batch(), option=orjson.OPT_INDENT_2)
    batch = read_batch(spaced)
    assert batch is not None and batch.drops == 2
    assert batch.records() == [(1, 2, 7, 7, 0), (2, 1, 7, 7, 1), (3, 1000, 8, 8, 1)]
