"""The decisions table is the rows written one by one and sorted by pandas, in a few array passes."""

from __future__ import annotations

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
    return pd.DataFrame(cols).sort_values(
        ["epoch", "link_class", "source", "target"], kind="stable", ignore_index=True
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
    pd.testing.assert_frame_equal(_decisions(d), _written_row_by_row(d))
