"""A run's headline numbers, summarised once (issue 25 §2): :func:`analysis.summarise`."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from analysis import RunData, robot_counts_line, summarise, team_errors
from analysis.metrics import formation_error, shape_error
from formation.scenario import Scenario
from testbed.sim.batch import run_batch
from testbed.sim.plan import plan_batch
from testbed.sim.simulate import simulate

EVENTS = Path(__file__).resolve().parents[3] / "scenarios" / "events.toml"
FINAL = ("final_formation_error_m", "final_shape_error_m")


@pytest.fixture(scope="module")
def events() -> Scenario:
    return Scenario.from_file(EVENTS)  # agent 5 leaves at 60 of 80


@pytest.fixture(scope="module")
def simulated(events: Scenario) -> RunData:
    return simulate(events, "estimate").record()


def as_recorded(run: RunData) -> RunData:
    """The same run as a recording holds it: no state of an agent out of the team."""
    x = np.where(run.present[..., None], run.positions, np.nan)
    s = run.scenario
    return dataclasses.replace(
        run, positions=x, present=np.zeros((0, 0), dtype=bool),
        formation_error=formation_error(x, s.edge_array, s.weights),
        shape_error=shape_error(x, s.edge_array, s.offsets),
    )  # fmt: skip


def test_the_team_errors_are_the_run_s_own_when_everyone_is_in_it() -> None:
    rng = np.random.default_rng(1)
    x = rng.normal(size=(4, 3, 2))
    edges, offsets = np.array([[1, 2], [2, 3], [1, 3]]), rng.normal(size=(3, 2))
    weights = np.ones(3)
    fe, se = formation_error(x, edges, weights), shape_error(x, edges, offsets)
    got = team_errors(x, np.ones((4, 3), dtype=bool), fe, se, edges, weights, offsets)
    assert got[0] is fe and got[1] is se
    team = np.ones((4, 3), dtype=bool)
    team[2, 2] = False  # epoch 2: agent 3 out, edge 1-2 only
    got = team_errors(x, team, fe, se, edges, weights, offsets)
    assert got[0][2] == formation_error(x[2], edges[:1], weights[:1])
    assert got[1][2] == shape_error(x[2], edges[:1], offsets)
    np.testing.assert_array_equal(np.delete(got[0], 2), np.delete(fe, 2))


def test_a_batch_s_team_errors_are_each_member_s(events: Scenario) -> None:
    """The sweep's final errors (a batch's arrays) equal each lone run's summary, bit for bit."""
    res = run_batch(plan_batch(events, [1, 2], events.epochs), "estimate", detail=True)
    formation, shape = res.team_errors()
    for b in range(2):
        got = res.member(b).summary()
        assert (got[FINAL[0]], got[FINAL[1]]) == (formation[-1, b], shape[-1, b])


def test_the_final_errors_are_the_team_s_not_a_departed_body_s(simulated: RunData) -> None:
    s = simulated.scenario
    got = summarise(simulated)
    kept = (s.edge_array != 5).all(axis=1)  # edges 3-5 and 4-5 left with agent 5
    last = simulated.positions[-1]
    assert got["final_shape_error_m"] == pytest.approx(
        float(shape_error(last, s.edge_array[kept], s.offsets)), rel=1e-12
    )
    bodies = simulate(s, "estimate").positions[-1]  # agent 5's body stays where it left
    assert np.isnan(last[4]).all(), "the record holds no state of an agent out of the team"
    assert got["final_shape_error_m"] < 0.05 < float(shape_error(bodies, s.edge_array, s.offsets))
    assert got["epochs"] == s.epochs and got["team"]["5"] == [(0, 60)]


def test_the_simulator_s_record_summarises_as_its_recording_would(simulated: RunData) -> None:
    ours, recorded = summarise(simulated), summarise(as_recorded(simulated))
    for name in (*FINAL, "team", "team_changes", "substitutions", "drops"):
        assert ours[name] == recorded[name], name


def test_the_simulate_summary_is_the_record_s(events: Scenario) -> None:
    result = simulate(events, "hold")
    full, short = summarise(result.record()), result.summary()
    assert list(short) == [
        "scenario", "strategy", "seed", "epochs", "final_formation_error_m",
        "peak_formation_error_m", "final_shape_error_m", "peak_shape_error_m", "substitutions",
        "substitution_cov_trace_m2", "fallbacks", "estimation_cov_trace_m2", "nees_mean", "drops",
        "longest_outage", "safety",
    ]  # fmt: skip
    assert all(short[k] == full[k] for k in short if k not in ("fallbacks",)), "one summary"
    assert short["fallbacks"] == result.fallbacks


def test_the_final_errors_are_at_the_last_epoch_with_a_state(simulated: RunData) -> None:
    cut = as_recorded(simulated)
    cut.positions = np.concatenate([cut.positions, np.full_like(cut.positions[:1], np.nan)])
    cut.formation_error = np.append(cut.formation_error, np.nan)
    cut.shape_error = np.append(cut.shape_error, np.nan)
    cut.present = np.concatenate([cut.present, np.zeros_like(cut.present[:1])])
    got = summarise(cut)
    for name in FINAL:
        assert got[name] == summarise(simulated)[name], name
    nothing = dataclasses.replace(cut, formation_error=np.full_like(cut.formation_error, np.nan))
    nothing.present = np.ones_like(cut.present)  # every state, no error: no final error
    assert summarise(nothing)["final_formation_error_m"] is None


def test_the_substitution_covariance_does_not_depend_on_the_rows_order(simulated: RunData) -> None:
    rows = simulated.substitution_errors

    def plain(e: np.ndarray) -> float:
        return float(np.trace(np.cov(e, rowvar=False)))

    rng = np.random.default_rng(1)
    shuffled = next(
        p for p in (rows[rng.permutation(len(rows))] for _ in range(50)) if plain(p) != plain(rows)
    )  # an order in which the plain sum rounds differently
    again = summarise(dataclasses.replace(simulated, substitution_errors=shuffled))
    assert repr(again["substitution_cov_trace_m2"]) == repr(
        summarise(simulated)["substitution_cov_trace_m2"]
    )


def test_the_robots_line_counts_poses_with_no_frame_id_only_when_there_are_some() -> None:
    counts = {"poses": 10, "bad_poses": 1, "jumps": 2, "wrong_frame": 3, "resent": 4}
    line = robot_counts_line(counts)
    assert line == (
        "robots: 10 poses, 6 rejected (1 not finite, 2 jumps, 3 in another frame), 0 commands "
        "clipped to the speed limit, 4 re-sent between steps"
    )
    assert robot_counts_line({**counts, "empty_frame": 5}) == (
        f"{line}, 5 with no frame_id (taken as declared)"
    )
