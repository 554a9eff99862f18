"""A run's queues from its records: per-queue numbers and the losses split by where."""

from __future__ import annotations

import pytest

from analysis.queues import Judged, loss_split, queue_table


def records() -> list[Judged]:
    return [
        Judged(0, "pass", "", "medium ap", 0, 10.0),
        Judged(0, "pass", "", "medium ap", 1, 30.0),
        Judged(0, "drop", "queue_full", "medium ap", 2, 0.0),
        Judged(1, "drop", "queue_late", "medium ap", 4, 700.0),
        Judged(1, "drop", "bernoulli", None, None, None),
        Judged(1, "pass", "", "radio 2", 0, 5.0),
        Judged(1, "drop", "oversize", "radio 2", 0, 0.0),
    ]


def test_losses_split_into_channel_queue_and_deadline() -> None:
    assert loss_split(records()) == {"channel": 1, "queue": 2, "deadline": 1}


def test_each_queue_has_its_load_throughput_depth_and_drops() -> None:
    table = queue_table(records(), epochs=2)
    assert list(table) == ["medium ap", "radio 2"]
    ap = table["medium ap"]
    assert (ap["offered"], ap["passed"]) == (4, 2)
    assert (ap["offered_per_epoch"], ap["throughput_per_epoch"]) == (2.0, 1.0)
    assert ap["drops"] == {"queue_full": 1, "queue_late": 1}
    assert ap["mean_depth"] == pytest.approx(7 / 4) and ap["max_depth"] == 4
    assert ap["mean_sojourn_ms"] == pytest.approx(20.0)  # passed packets only
    assert ap["max_depth_by_epoch"] == {"0": 2, "1": 4}
    assert table["radio 2"]["drops"] == {"oversize": 1}
