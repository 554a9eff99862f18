"""keys.parse reads back every key the module builds: its function, run id and arguments."""

from __future__ import annotations

import pytest

from formation import keys

RUN = "run-1"
BUILT = [
    (keys.agent_state(RUN, 3), "agent_state", ("3",)),
    (keys.agent_report(RUN, 3), "agent_report", ("3",)),
    (keys.leader_estimate_out(RUN), "leader_estimate_out", ()),
    (keys.leader_estimate_for(RUN, 4), "leader_estimate_for", ("4",)),
    (keys.link_state(RUN, 1, 2), "link_state", ("1", "2")),
    (keys.link_report(RUN, 5), "link_report", ("5",)),
    (keys.link_estimate(RUN, 5), "link_estimate", ("5",)),
    (keys.inbox(RUN, 0, "report"), "inbox", ("0", "report")),
    (keys.netem_decision(RUN), "netem_decision", ()),
    (keys.netem_change(RUN), "netem_change", ()),
    (keys.status(RUN, "agent", 2), "status", ("agent", "2")),
    (keys.metrics(RUN), "metrics", ()),
    (keys.alive(RUN, "leader", 0), "alive", ("leader", "0")),
    (keys.start(RUN), "alive", ("clock", "start")),
    (keys.scene(RUN), "scene", ()),
    (keys.frames(RUN), "frames", ()),
    (keys.log(RUN), "log", ()),
    (keys.flush(RUN), "flush", ()),
    (keys.clock(RUN), "clock", ()),
    (
        keys.body(RUN, 2, "pose", "geometry_msgs/msg/Pose"),
        "body",
        ("2", "pose", "geometry_msgs/msg/Pose"),
    ),
]


@pytest.mark.parametrize(("key", "kind", "args"), BUILT, ids=[b[1] + b[0][-8:] for b in BUILT])
def test_parse_reads_back_what_keys_build(key: str, kind: str, args: tuple[str, ...]) -> None:
    assert keys.parse(key) == (kind, RUN, args)


def test_a_key_no_function_builds_has_no_kind() -> None:
    assert keys.parse(f"formation/{RUN}/agent/3/colour") == ("", RUN, ())
    assert keys.parse("elsewhere/run/agent/3/state") == ("", "", ())
    assert keys.parse(keys.link_state(RUN, 7, 5).replace("state", "estimate")).kind == ""
