"""The decisions table is the rows written one by one and sorted by pandas, in a few array passes."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pandas as pd
from hypothesis import given, settings
from hypothesis import strategies as st

from analysis.record import DECISION_COLUMNS, Decisions
from analysis.tables import _decisions

_ROWS = st.lists(
    st.tuples(
        st.integers(-1, 4),  # epoch
        st.sampled_from(["state", "report", "estimate"]),
        st.sampled_from(["formation", "report", "estimate"]),
        st.integers(0, 12),  # source
        st.integers(0, 12),  # target
        st.sampled_from(["pass", "drop", "delayed", "duplicate"]),
        st.integers(0, 2),  # delay_epochs
    ),
    max_size=60,
)


def _written_row_by_row(d: Decisions) -> pd.DataFrame:
    """The table as it was made: a name per row, then pandas' stable sort of the columns."""
    cols = {
        "epoch": d.epoch,
        "phase": d.phase,
        "link_class": d.link_class,
        "source": d.source,
        "target": d.target,
        "link": np.array([f"{a}->{b}" for a, b in zip(d.source, d.target, strict=True)], object),
        "seq": d.seq,
        "verdict": d.verdict,
        "on_time": d.on_time,
        "delay_epochs": d.delay_epochs,
        "delay_ms": d.delay_ms,
        "model": d.model,
        "state": d.state,
    }
    texts = ("phase", "link_class", "link", "verdict", "model", "state")
    return (
        pd.DataFrame(cols)
        .sort_values(["epoch", "link_class", "source", "target"], kind="stable", ignore_index=True)
        .astype({t: pd.CategoricalDtype(pd.Index(sorted(set(cols[t])), dtype=str)) for t in texts})
    )


def _decisions_of(rows: list[tuple[Any, ...]]) -> Decisions:
    full = [
        (k, phase, cls, a, b, seq, verdict, delay, 0.5 * seq, f"m{seq % 3}", "", None, None, None)
        for seq, (k, phase, cls, a, b, verdict, delay) in enumerate(rows)
    ]
    assert all(len(row) == len(DECISION_COLUMNS) for row in full)
    return Decisions.of_rows(full)


@settings(max_examples=50, deadline=None)
@given(rows=_ROWS)
def test_the_decisions_table_is_the_row_by_row_table(rows: list[tuple[Any, ...]]) -> None:
    d = _decisions_of(rows)
    expected = _written_row_by_row(d)
    pd.testing.assert_frame_equal(_decisions(d), expected)
    coded = {}  # the text columns as a reader gives them: codes into their values
    for name in ("phase", "link_class", "verdict", "model", "state"):
        values, codes = np.unique(getattr(d, name).astype(str), return_inverse=True)
        coded[name] = (len(values) - 1 - codes, values[::-1].astype(object))  # not sorted
    table = _decisions(dataclasses.replace(d, coded=coded))
    pd.testing.assert_frame_equal(table, expected)
    assert (table["verdict"] == "pass").tolist() == [v == "pass" for v in expected["verdict"]]
    np.testing.assert_array_equal(d.on_time, dataclasses.replace(d, coded=coded).on_time)
