"""Scenario events (issue 20): the loader's refusals, and the membership every process derives."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from formation.errors import ScenarioError
from formation.scenario import Scenario, load

SCENARIOS = Path(__file__).resolve().parents[3] / "scenarios"


def with_events(paper: Scenario, *events: tuple[int, int, str], **more: object) -> Scenario:
    rows = [{"epoch": k, "agent": i, "action": a} for k, i, a in events]
    return paper.with_overrides(events=rows, **more)


@pytest.mark.parametrize(
    ("events", "match"),
    [
        ([(10, 9, "crash")], r"events\[0\]\.agent = 9; agent does not exist \(agents are 1\.\.5\)"),
        ([(60, 3, "crash")], r"events\[0\]\.epoch = 60; past the end \(epochs = 50"),
        ([(50, 3, "crash")], r"events\[0\]\.epoch = 50; past the end"),
        ([(10, 3, "restart")], r"events\[0\]\.action = 'restart'; agent 3 is present at epoch 10: "
                               "a restart needs a crash"),
        ([(10, 3, "crash"), (20, 3, "join")], r"events\[1\]\.action = 'join'; agent 3 is crashed"),
        ([(10, 3, "join"), (20, 3, "join")], r"events\[1\]\.action = 'join'; agent 3 is present"),
        ([(20, 3, "restart"), (10, 3, "crash"), (30, 3, "restart")],
         r"events\[2\]\.action = 'restart'; agent 3 is present at epoch 30"),
        ([(10, 3, "leave"), (10, 3, "join")], r"events\[1\]\.epoch = 10; agent 3 has another event"),
        ([(10, 1, "leave")], r"events\[0\]\.agent = 1; the reference agent"),
        ([(10, 4, "leave"), (10, 3, "crash")], r"events\[\d\]\.action = '(leave|crash)'; from "
                                               r"epoch 10 the team taking part is split into "
                                               r"\[1, 2\] and \[5\]; set allow_split = true"),
        ([(10, 3, "fly")], r"events\[0\]\.action = 'fly'; Input should be"),
    ],
)  # fmt: skip
def test_bad_events_are_refused_naming_the_field_and_value(
    paper: Scenario, events: list[tuple[int, int, str]], match: str
) -> None:
    with pytest.raises(ScenarioError, match=match):
        with_events(paper, *events)


def test_a_bad_event_in_a_file_names_the_file(tmp_path: Path) -> None:
    text = (
        SCENARIOS / "paper.toml"
    ).read_text() + '\n[[events]]\nepoch = 7\nagent = 3\naction = "restart"\n'
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ScenarioError, match=r"^.*bad\.toml: events\[0\]\.action = 'restart'; "):
        load(path)


def test_a_split_is_allowed_when_the_scenario_says_so(paper: Scenario) -> None:
    s = with_events(paper, (10, 4, "leave"), (10, 3, "crash"), allow_split=True)
    assert s.membership.taking_part(10) == [1, 2, 5]


def test_membership_of_each_action(paper: Scenario) -> None:
    s = with_events(paper, (10, 3, "crash"), (20, 3, "restart"), (30, 5, "leave"), (5, 4, "join"))
    m = s.membership
    assert m.present.shape == (51, 5)
    np.testing.assert_array_equal(np.flatnonzero(~m.present[:, 2]), np.arange(10, 20))
    assert m.in_graph[:, 2].all(), "a crashed agent's edges stay (its packets are lost)"
    assert not m.present[30:, 4].any() and not m.in_graph[30:, 4].any() and m.present[:30, 4].all()
    assert not m.in_graph[:5, 3].any() and m.present[5:, 3].all(), "absent until it joins"
    assert m.incarnations(3) == [(0, 10), (20, 50)] and m.incarnations(5) == [(0, 30)]
    assert m.incarnations(4) == [(5, 50)]
    assert np.flatnonzero(m.starts.any(axis=1)).tolist() == [5, 20]
    assert not with_events(paper).events and paper.membership.everyone


def test_the_shipped_event_scenario_loads() -> None:
    s = Scenario.from_file(SCENARIOS / "events.toml")
    assert {e.action for e in s.events} == {"crash", "restart", "leave", "join"}
    assert not s.membership.everyone
