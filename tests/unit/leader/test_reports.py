"""The leader reads its token reports into the directed links' columns: a measurement counts
on its own link only, with a token of 1 and ``d`` coordinates; of two, the later."""

from __future__ import annotations

import numpy as np

from formation.messages import Measurement, TokenReport
from formation.scenario import Scenario
from leader.wire import LinkIndex, reports_to_measurements
from testbed.sim.team_generators import henneberg_team


def _report(agent: int, *measurements: tuple[int, int, list[float] | None]) -> TokenReport:
    return TokenReport(
        run_id="r", sender=f"agent/{agent}", seq=0, epoch=0, stamp_ns=1, agent=agent,
        measurements=[Measurement(neighbour=j, token=t, z=z) for j, t, z in measurements],
    )  # fmt: skip


def _one_by_one(scenario: Scenario, reports: list[TokenReport]) -> tuple[np.ndarray, np.ndarray]:
    """The rule written out, a measurement at a time."""
    rows = {(a, b): r for r, (a, b) in enumerate(scenario.directed_links.tolist())}
    known = np.zeros(len(rows), dtype=bool)
    z = np.zeros((len(rows), scenario.dimension))
    for report in reports:
        for m in report.measurements:
            row = rows.get((m.neighbour, report.agent))
            whole = m.z is not None and len(m.z) == scenario.dimension
            if row is not None and m.token == 1 and whole:
                known[row], z[row] = True, m.z
    return known, z


def _random_report(rng: np.random.Generator, n: int) -> TokenReport:
    """Any sender, neighbours in and out of the team, tokens, 1–3 coordinates or none."""
    measurements = []
    for _ in range(int(rng.integers(0, 8))):
        size = int(rng.integers(1, 4))
        z = None if rng.random() < 0.1 else rng.standard_normal(size).tolist()
        measurements.append((int(rng.integers(-1, n + 3)), int(rng.integers(0, 2)), z))
    return _report(int(rng.integers(1, n + 1)), *measurements)


def test_only_a_whole_measurement_on_a_link_counts_and_the_later_wins() -> None:
    scenario = henneberg_team(6)
    j, i = (int(v) for v in scenario.directed_links[0])  # the link j → i
    outsider = next(
        a
        for a in range(1, 7)
        if a != i and (a, i) not in map(tuple, scenario.directed_links.tolist())
    )
    reports = [
        _report(i, (j, 1, [0.5, -0.25]), (outsider, 1, [9.0, 9.0]), (-3, 1, [9.0, 9.0])),
        _report(i, (j, 1, [1.5, 2.5])),  # the same link again: this one
        _report(j, (i, 0, [7.0, 7.0]), (i, 1, [7.0])),  # token 0; one coordinate of two
        _report(99, (j, 1, [9.0, 9.0])),  # no such agent
    ]
    known, z = reports_to_measurements(scenario, reports)
    assert np.flatnonzero(known).tolist() == [0]
    assert z[0].tolist() == [1.5, 2.5] and not z[1:].any()


def test_the_columns_equal_the_rule_one_measurement_at_a_time(seed: int) -> None:
    scenario = henneberg_team(40)
    rng = np.random.default_rng(seed)
    index = LinkIndex(scenario.directed_links, scenario.n)
    for _ in range(20):
        reports = [_random_report(rng, 40) for _ in range(int(rng.integers(0, 120)))]
        known, z = reports_to_measurements(scenario, reports, index)
        want_known, want_z = _one_by_one(scenario, reports)
        assert np.array_equal(known, want_known) and np.array_equal(z, want_z)


def test_a_neighbour_past_64_bits_is_on_no_link() -> None:
    """A valid report may name any integer (the model reads it): such a measurement counts
    on no link, and the others of the report still count."""
    scenario = henneberg_team(6)
    j, i = (int(v) for v in scenario.directed_links[0])
    report = _report(i, (2**70, 1, [9.0, 9.0]), (j, 1, [0.5, 0.25]), (-(2**70), 1, [9.0, 9.0]))
    known, z = reports_to_measurements(scenario, [report])
    assert np.flatnonzero(known).tolist() == [0] and z[0].tolist() == [0.5, 0.25]
