"""An agent set's messages made from columns are exactly what the wire models validate, with
the values they were made from, alone and in a pool's bundle."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from agent.outgoing import Reports, bundle_message, state_messages, states_bundle
from formation.messages import Bundle, CoordinationState, TokenReport
from shell import MemoryBus, Service

SENDER = Service(MemoryBus(), 'run "quoted" \\ 100%', "pool", 3)  # escapes, and a % in the run
HEAD = SENDER.header_format()
floats = st.floats(allow_nan=False, allow_infinity=False)
pairs = st.lists(st.tuples(floats, floats), min_size=1, max_size=4)
substitutes = st.lists(st.tuples(st.integers(1, 99), st.lists(floats, min_size=2, max_size=2), st.booleans()), max_size=3)  # fmt: skip


@given(pairs, st.data(), st.booleans(), st.booleans())
def test_states_validate_with_every_field(
    xy: list[tuple[float, float]], data: st.DataObject, unicycle: bool, silent: bool
) -> None:
    a = len(xy)
    agents = list(range(3, 3 + a))
    subs = [data.draw(substitutes) for _ in agents]
    poses = (
        [(data.draw(floats), data.draw(st.integers(0, 9))) for _ in agents] if unicycle else None
    )
    positions = np.array(xy)
    made = state_messages(HEAD, list(range(a)), 9, 17, agents, positions, subs, poses, silent)
    for n, text in enumerate(made):
        msg = CoordinationState.model_validate_json(text)
        assert (msg.run_id, msg.sender, msg.seq, msg.epoch, msg.stamp_ns) == (
            SENDER.run_id, "pool/3", n, 9, 17)  # fmt: skip
        assert msg.agent == agents[n] and msg.position == list(xy[n]) and msg.velocity is None
        assert [(s.neighbour, s.value, s.fallback) for s in msg.substituted] == subs[n]
        assert (msg.heading, msg.saturated) == (poses[n] if poses else (None, None))
        assert msg.robot_silent is silent


@given(st.lists(st.tuples(st.integers(1, 4), st.integers(5, 99), st.booleans(), floats, floats), max_size=8))  # fmt: skip
def test_reports_list_each_in_link_of_their_agent_in_link_order(
    links: list[tuple[int, int, bool, float, float]],
) -> None:
    agents = [1, 2, 3, 4]
    receivers, senders = [i for i, *_ in links], [j for _, j, *_ in links]
    arrived = np.array([a for _, _, a, _, _ in links], dtype=bool)
    z = np.array([(x, y) for *_, x, y in links]).reshape(-1, 2)
    made = Reports(agents, receivers, senders).messages(HEAD, [5, 6, 7, 8], 2, 1, arrived, z)
    for n, text in enumerate(made):
        msg = TokenReport.model_validate_json(text)
        assert msg.agent == agents[n] and msg.seq == 5 + n and not msg.robot_silent
        assert [(m.neighbour, m.token, m.z) for m in msg.measurements] == [
            (j, int(a), [x, y] if a else None) for i, j, a, x, y in links if i == agents[n]
        ]


@given(pairs, st.data(), st.booleans())
def test_a_bundle_carries_each_message_as_it_would_go_alone(
    xy: list[tuple[float, float]], data: st.DataObject, silent: bool
) -> None:
    a = len(xy)
    agents, seqs = list(range(3, 3 + a)), list(range(10, 10 + a))
    subs = [data.draw(substitutes) for _ in agents]
    poses = [(data.draw(floats), 2) for _ in agents]
    made = {  # alone, and as a bundle's strings
        quote: state_messages(HEAD, seqs, 4, 1, agents, np.array(xy), subs, poses, silent, quote)
        for quote in (False, True)
    }
    bundle = Bundle.model_validate_json(
        bundle_message(HEAD, 7, 4, 2, "state", agents, seqs, made[True])
    )
    assert (bundle.sender, bundle.seq, bundle.epoch, bundle.phase) == ("pool/3", 7, 4, "state")
    assert [(p.agent, p.seq, p.message.encode()) for p in bundle.parts] == list(
        zip(agents, seqs, made[False], strict=True)
    )
    reports = Reports(agents, agents, [1] * a)
    arrived, z = np.array([n % 2 == 0 for n in range(a)]), np.array(xy)
    alone, quoted = (
        reports.messages(HEAD, seqs, 4, 1, arrived, z, silent, q) for q in (False, True)
    )
    bundle = Bundle.model_validate_json(
        bundle_message(HEAD, 8, 4, 2, "report", agents, seqs, quoted)
    )
    assert [p.message.encode() for p in bundle.parts] == alone


@settings(max_examples=40)
@given(pairs, st.data(), st.booleans(), st.booleans())
def test_a_bundle_made_at_once_has_the_bytes_of_its_messages_bundled(
    xy: list[tuple[float, float]], data: st.DataObject, silent: bool, unicycle: bool
) -> None:
    a = len(xy)
    agents, seqs = list(range(3, 3 + a)), data.draw(st.lists(st.integers(0, 99), min_size=a, max_size=a))  # fmt: skip
    subs = [data.draw(substitutes) for _ in agents]
    poses = [(data.draw(floats), 2) for _ in agents] if unicycle else None
    quoted = state_messages(HEAD, seqs, 4, 1, agents, np.array(xy), subs, poses, silent, True)
    assert states_bundle(HEAD, 7, 4, 1, agents, seqs, np.array(xy), subs, poses, silent) == (
        bundle_message(HEAD, 7, 4, 1, "state", agents, seqs, quoted)
    )
    receivers = data.draw(st.lists(st.sampled_from(agents), max_size=3 * a))
    arrived = np.array(data.draw(st.lists(st.booleans(), min_size=len(receivers), max_size=len(receivers))), dtype=bool)  # fmt: skip
    z = np.array([data.draw(st.tuples(floats, floats)) for _ in receivers]).reshape(-1, 2)
    reports = Reports(agents, receivers, [1 + n for n in range(len(receivers))])
    for arrived_now in (arrived, np.ones_like(arrived)):  # some links lost, and none
        quoted = reports.messages(HEAD, seqs, 4, 1, arrived_now, z, silent, True)
        assert reports.bundle(HEAD, 8, 4, 1, seqs, arrived_now, z, silent) == (
            bundle_message(HEAD, 8, 4, 1, "report", agents, seqs, quoted)
        )
