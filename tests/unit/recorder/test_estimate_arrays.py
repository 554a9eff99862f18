"""A leader's estimate as arrays: what the trust gate checks and the reader keeps."""

from __future__ import annotations

import json
import re
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from formation import keys
from formation.scenario import Scenario
from recorder.reading.estimates import estimate_arrays, estimates
from recorder.reading.skips import INVALID, OUT_OF_RANGE
from recorder.reading.trust import Gate
from recorder.reading.value_checks import rows_of

RUN = "r"


def _estimate(scenario: Scenario, **changes: Any) -> dict[str, Any]:
    n = scenario.n
    edges = [[int(a), int(b)] for a, b in scenario.edge_array]
    return {
        "run_id": RUN, "sender": "leader", "seq": 0, "epoch": 2, "stamp_ns": 0,
        "kind": "estimate", "positions": [[0.5 + i, 1.0] for i in range(n - 1)] + [None],
        "covariances": [[[1.0 + i, 0.1], [0.1, 2.0]] for i in range(n - 1)] + [None],
        "observable": [True] * (n - 1) + [False], "tree": edges[:2],
        "healthy": [edges[0][::-1], *edges[1:]], "components": 1, "rigidity_rank": 3,
        "rigid": True, "x_ref": [0.0, 0.0], "v_ref": [0.0, 0.0], "reports_received": n,
        **changes,
    }  # fmt: skip


@pytest.mark.parametrize("plain", [True, False])
@pytest.mark.parametrize(
    ("change", "reason", "detail"),
    [
        (("positions", 1, [1e400, 0.0]), INVALID, "estimate is not finite"),
        (("positions", 1, [1.0, 2.0, 3.0]), INVALID, "estimate has 3 components, expected 2"),
        (("covariances", 2, [[1.0, 0.0], [0.0, 1e400]]), INVALID, "covariance row is not finite"),
        (("covariances", 2, [[1.0, 0.0]]), INVALID, "a covariance with 1 rows, expected 2"),
        (("covariances", 2, [[1.0, 0.0], [0.0]]), INVALID, "covariance row has 1 components"),
        (("tree", 1, [2, 5]), OUT_OF_RANGE, r"edge \(2, 5\) not in the formation"),
        (("healthy", 0, [1, 2**63]), OUT_OF_RANGE, r"edge \(1, 9223372036854775808\) not in"),
    ],
)
def test_a_defect_in_one_entry_is_refused_and_named(
    paper: Scenario, plain: bool, change: tuple[str, int, Any], reason: str, detail: str
) -> None:
    field, at, value = change
    body = _estimate(paper)
    body[field] = [*body[field]]
    body[field][at] = value
    gate = Gate(paper, plain_bulk=plain)
    topic = keys.leader_estimate_out(RUN)
    assert gate.check(topic, json.dumps(body).encode()) is None
    ((_, got_reason, got_detail),) = gate.skipped.examples
    assert got_reason == reason
    assert re.search(detail, got_detail), got_detail


def test_the_arrays_hold_the_lists(paper: Scenario) -> None:
    body = _estimate(paper, positions=[[1.0, 2.0], None, [3.0, 4.0], None, [5.0, 6.0]])
    msg = Gate(paper, plain_bulk=True).check(
        keys.leader_estimate_out(RUN), json.dumps(body).encode()
    )
    a = estimate_arrays(msg, 2)
    assert a is not None
    assert a.with_position.tolist() == [0, 2, 4]
    assert a.positions.tolist() == [[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]]
    assert a.with_covariance.tolist() == [0, 1, 2, 3]
    assert a.covariances[3].tolist() == [[4.0, 0.1], [0.1, 2.0]]
    assert a.tree.tolist() == body["tree"] and a.healthy.tolist() == body["healthy"]


@pytest.mark.parametrize(
    "positions", [[[1.0, 2.0], [3.0]], [[1.0, 2.0], [3.0, 4.0, 5.0]], [[1.0, "x"]]]
)
def test_entries_not_of_the_shape_give_no_arrays(positions: list[Any]) -> None:
    msg = SimpleNamespace(positions=positions, covariances=[], tree=[], healthy=[])
    assert estimate_arrays(msg, 2) is None


def test_the_run_arrays_are_the_estimates_agent_by_agent(paper: Scenario) -> None:
    """Rows set from the arrays: each agent's position and block where given, NaN elsewhere."""
    body = _estimate(paper, positions=[[1.0, 2.0], None, [3.0, 4.0], None, [5.0, 6.0]])
    msg = Gate(paper).check(keys.leader_estimate_out(RUN), json.dumps(body).encode())
    out = estimates(paper, {2: msg}, 3)
    assert out["estimated"].tolist() == [False, False, True]
    for i in range(paper.n):
        given = body["positions"][i]
        want = np.full(2, np.nan) if given is None else np.array(given)
        np.testing.assert_array_equal(out["estimates"][2, i], want)
        block = body["covariances"][i]
        want = np.full((2, 2), np.nan) if block is None else np.array(block)
        np.testing.assert_array_equal(out["estimate_cov"][2, i], want)
    assert np.isnan(out["estimates"][:2]).all()
    assert out["tree"][2].sum() == 2 and out["healthy"][2].all()


def test_rows_of_nested_lists_are_numpy_s_arrays_or_none() -> None:
    rows = [[[1.0 + i, 0.1], [0.1, 2.0 * i]] for i in range(5)]
    np.testing.assert_array_equal(rows_of(rows, (2, 2)), np.array(rows))
    np.testing.assert_array_equal(rows_of([r[0] for r in rows], (2,)), np.array(rows)[:, 0])
    assert rows_of([], (2,)).shape == (0, 2)  # type: ignore[union-attr]
    for bad, shape in [
        ([[1.0, 2.0], [3.0]], (2,)),  # ragged
        ([[[1.0, 2.0], [3.0]]], (2, 2)),  # ragged inside
        ([[1.0, 2.0], None], (2,)),  # not a row
        ([[1.0, "x"]], (2,)),  # not a number
        ([[1.0, 2.0]], (2, 2)),  # too shallow
    ]:
        assert rows_of(bad, shape) is None, bad
