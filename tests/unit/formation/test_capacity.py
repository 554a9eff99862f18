"""``[[network.capacity]]``: scopes, the links each queue serves, and bad entries refused by name."""

from __future__ import annotations

from pathlib import Path

import pytest

from formation.capacity import Capacity, all_links, members, queues_of, unknown_medium
from formation.errors import ScenarioError
from formation.scenario import load
from testkit.scenario_files import TRIANGLE, scenario_file

GOOD = """
[[network.capacity]]
scope = "link"
link = [3, 0]
rate_bps = 64000
limit_packets = 4
[[network.capacity]]
scope = "radio"
agent = 2
rate_bps = 1e6
burst_bytes = 3000
[[network.capacity]]
scope = "medium"
medium = "ap"
links = "control"
rate_bps = 2e6
policy = "oldest"
"""


def write(tmp_path: Path, text: str) -> Path:
    return scenario_file(tmp_path, text, "cap.toml")


def test_scopes_resolve_to_their_links_in_queue_order(tmp_path: Path) -> None:
    s = load(write(tmp_path, TRIANGLE + GOOD))
    caps = s.network.capacity
    links = all_links(s.n, s.directed_links.tolist())
    assert members(caps[0], links) == [(3, 0)]
    assert sorted(members(caps[1], links)) == [(2, 0), (2, 1), (2, 3)]
    assert sorted(members(caps[2], links)) == sorted(
        [(1, 0), (2, 0), (3, 0), (0, 1), (0, 2), (0, 3)]
    )
    by_link = queues_of(caps, links)
    assert by_link[(3, 0)] == (0, 2)  # its link's queue, then the access point's
    assert by_link[(2, 0)] == (1, 2)  # the radio before the medium
    assert by_link[(2, 1)] == (1,)
    assert (1, 2) not in by_link
    assert [c.name for c in caps] == ["link 3->0", "radio 2", "medium ap"]
    assert unknown_medium(caps, "ap") is None
    assert unknown_medium(caps, "wifi") == "unknown medium; the media are ['ap']"


BAD = [
    (
        "rate 0",
        'scope = "link"\nlink = [1, 2]\nrate_bps = 0',
        r"cap\.toml: network\.capacity\[0\]\.rate_bps = 0; .*greater than 0",
    ),
    (
        "negative rate",
        'scope = "link"\nlink = [1, 2]\nrate_bps = -5.0',
        r"cap\.toml: network\.capacity\[0\]\.rate_bps = -5\.0; .*greater than 0",
    ),
    (
        "limit 0",
        'scope = "link"\nlink = [1, 2]\nrate_bps = 1e5\nlimit_packets = 0',
        r"cap\.toml: network\.capacity\[0\]\.limit_packets = 0; .*greater than or equal to 1",
    ),
    (
        "byte limit 0",
        'scope = "radio"\nagent = 1\nrate_bps = 1e5\nlimit_bytes = 0',
        r"cap\.toml: network\.capacity\[0\]\.limit_bytes = 0; .*greater than or equal to 1",
    ),
    (
        "unknown policy",
        'scope = "radio"\nagent = 1\nrate_bps = 1e5\npolicy = "newest"',
        r"cap\.toml: network\.capacity\[0\]\.policy = 'newest'; .*'tail' or 'oldest'",
    ),
    (
        "no such link",
        'scope = "link"\nlink = [2, 2]\nrate_bps = 1e5',
        r"cap\.toml: network\.capacity\[0\]\.link = \[2, 2\]; not a link of the run",
    ),
    (
        "radio of no agent",
        'scope = "radio"\nagent = 9\nrate_bps = 1e5',
        r"cap\.toml: network\.capacity\[0\]\.agent = 9; agent does not exist",
    ),
    (
        "scope without its field",
        'scope = "medium"\nrate_bps = 1e5\nlinks = "all"',
        r"cap\.toml: network\.capacity\[0\]\.medium = None; scope 'medium' needs medium",
    ),
    (
        "unknown medium selector",
        'scope = "medium"\nmedium = "ap"\nrate_bps = 1e5\nlinks = "wifi"',
        r"cap\.toml: network\.capacity\[0\]\.links = 'wifi'; expected \[\[i, j\], \.\.\.\] "
        r"or one of control, formation, all",
    ),
    (
        "a link in two media",
        'scope = "medium"\nmedium = "ap"\nrate_bps = 1e5\nlinks = "control"\n'
        '[[network.capacity]]\nscope = "medium"\nmedium = "mesh"\nrate_bps = 1e5\n'
        "links = [[1, 2], [0, 3]]",
        r"cap\.toml: network\.capacity\[1\]\.links\[1\] = \[0, 3\]; link already in medium 'ap'",
    ),
    (
        "a medium defined twice",
        'scope = "medium"\nmedium = "ap"\nrate_bps = 1e5\nlinks = [[1, 2]]\n'
        '[[network.capacity]]\nscope = "medium"\nmedium = "ap"\nrate_bps = 1e5\n'
        "links = [[2, 1]]",
        r"cap\.toml: network\.capacity\[1\]\.medium = 'ap'; medium already defined by \[0\]",
    ),
]


@pytest.mark.parametrize(("case", "entry", "pattern"), BAD, ids=[b[0] for b in BAD])
def test_bad_capacity_is_refused_with_file_field_and_value(
    tmp_path: Path, case: str, entry: str, pattern: str
) -> None:
    with pytest.raises(ScenarioError, match=pattern):
        load(write(tmp_path, TRIANGLE + "[[network.capacity]]\n" + entry + "\n"))


def test_a_capacity_round_trips_through_the_resolved_toml(tmp_path: Path) -> None:
    s = load(write(tmp_path, TRIANGLE + GOOD))
    again = load(write(tmp_path, s.to_toml()))
    assert again.network.capacity == s.network.capacity
    assert isinstance(again.network.capacity[0], Capacity)
