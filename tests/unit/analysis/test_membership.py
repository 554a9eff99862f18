"""Who was in the team at each epoch, its changes and their transients (issue 20 item 4)."""

from __future__ import annotations

import numpy as np

from analysis.membership import changes, present, spans, team_errors, team_shape_error
from analysis.metrics import formation_error, shape_error


def test_a_loss_and_a_return_are_changes_with_the_epochs_back_under_the_threshold() -> None:
    edges = np.array([[1, 2], [2, 3], [1, 3]])
    offsets = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    x = np.repeat(offsets[None], 10, axis=0).copy()  # (10, 3, 2): held shape
    x[3:6, 2] = np.nan  # agent 3 absent at epochs 3-5
    x[6:8, 2] += 0.5  # back displaced: two epochs over the threshold
    team = present(x)
    assert spans(team) == {1: [(0, 9)], 2: [(0, 9)], 3: [(0, 2), (6, 9)]}
    shape = team_shape_error(x, edges, offsets)
    assert np.isfinite(shape).all() and shape[4] == 0.0  # edge 1-2 only while 3 is away
    got = [(c.epoch, c.agent, c.what, c.transient_epochs) for c in changes(team, shape, 0.05)]
    assert got == [(3, 3, "lost", 0), (6, 3, "back", 2)]


def test_a_full_team_has_no_change() -> None:
    x = np.zeros((5, 4, 2))
    assert changes(present(x), np.zeros(5)) == []


def test_the_errors_over_chosen_edges_are_those_of_the_edges_kept() -> None:
    rng = np.random.default_rng(3)
    x = rng.normal(size=(6, 4, 2))  # (P, n, d)
    edges = np.array([[1, 2], [2, 3], [3, 4], [1, 4]])
    offsets, weights = rng.normal(size=(4, 2)), np.ones(4)
    on = np.ones((6, 4), dtype=bool)
    on[2, [1, 2]] = False  # epoch 2: edges 1-2 and 1-4 only
    on[4] = False  # epoch 4: no edge
    for metric, arg in ((shape_error, offsets), (formation_error, weights)):
        got = metric(x, edges, arg, on)
        np.testing.assert_allclose(got[[0, 1, 3, 5]], metric(x, edges, arg)[[0, 1, 3, 5]])
        kept = metric(x[2], edges[[0, 3]], arg if metric is shape_error else weights[[0, 3]])
        assert got[2] == kept and np.isnan(got[4])


def test_a_change_the_scenario_planned_is_named_by_its_event() -> None:
    team = np.ones((12, 4), dtype=bool)
    team[:4, 3] = False  # agent 4 joins at 4
    team[6:9, 2] = False  # agent 3 crashes at 5 (its last state x[5]) and restarts at 9
    team[10:, 1] = False  # agent 2 leaves at 9 (its last state x[9])
    team[3:7, 0] = False  # agent 1 lost at 3, back at 7: no event says so
    events = [(4, 4, "join"), (5, 3, "crash"), (9, 3, "restart"), (9, 2, "leave")]
    got = [(c.epoch, c.agent, c.what) for c in changes(team, np.zeros(12), events=events)]
    assert got == [(3, 1, "lost"), (4, 4, "join"), (5, 3, "crash"), (7, 1, "back"),
                   (9, 2, "leave"), (9, 3, "restart")]  # fmt: skip
    unplanned = [(c.epoch, c.what) for c in changes(team, np.zeros(12)) if c.agent == 3]
    assert unplanned == [(6, "lost"), (9, "back")]


def test_the_final_errors_are_the_team_s_at_the_end_and_the_run_s_when_all_take_part() -> None:
    edges = np.array([[1, 2], [2, 3], [1, 3]])
    offsets = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    weights = np.array([1.0, np.sqrt(2.0), 1.0])
    last = offsets + np.array([[0.0, 0.0], [0.0, 0.1], [5.0, 0.0]])  # agent 3 far off
    whole = formation_error(last, edges, weights), shape_error(last, edges, offsets)

    def final_team_errors(x: np.ndarray) -> tuple[float, float] | None:
        """The team's errors at the last epoch, None where they are the run's own."""
        team = present(x)
        if team.all():
            return None
        got = team_errors(x, team, *whole, edges, weights, offsets)
        return float(got[0]), float(got[1])

    assert final_team_errors(last) is None
    assert team_errors(last, present(last), *whole, edges, weights, offsets) == whole
    last[2] = np.nan  # agent 3 out of the team: only edge 1-2 counts
    got = final_team_errors(last)
    keep = np.array([[True, False, False]])
    pair = np.nan_to_num(last)[None]
    assert got == (
        float(formation_error(pair, edges, weights, keep)[0]),
        float(shape_error(pair, edges, offsets, keep)[0]),
    )
    assert got[1] == 0.1 and got[0] < 0.01  # agent 2's 0.1 m off its slot, not agent 3's 5 m
