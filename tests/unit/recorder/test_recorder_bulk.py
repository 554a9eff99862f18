"""The bulk path of a recording's reader gives what the model's path gives, message by message and run by run.

:class:`~recorder.reading.trust.Gate` with ``plain_bulk`` decodes agents' states and
netem's decisions with orjson and falls back to the pydantic model for what it cannot vouch
for; both gates must pass and refuse the same payloads with the same reasons, and return the
same values. ``decode_run(bulk=False)`` is the model's path over the whole recording.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from pydantic import BaseModel, Field, field_validator

from analysis import Decisions
from formation import keys
from formation.scenario import Scenario
from formation.structs import struct_of
from recorder.reading.chunks import ChunkError, chunk_messages, file_order
from recorder.reading.reader import open_recording
from recorder.reading.run import decode_run
from recorder.reading.state_batch import StateBlock, judge_states
from recorder.reading.trust import Gate
from testkit.forgeries import forgeries

RUN = "synthetic"
EPOCH_NS = 1_000_000_000


def _values(msg: Any) -> Any:
    """A message's fields, nested, as plain values (a model or a struct alike)."""
    if isinstance(msg, list):
        return [_values(v) for v in msg]
    names = getattr(msg, "__struct_fields__", None) or getattr(type(msg), "model_fields", None)
    if names is None:
        return repr(msg)  # repr: -0.0 and 0.0, an int and a float, told apart
    return {name: _values(getattr(msg, name)) for name in names}


def _both(scenario: Scenario, topic: str, data: bytes, kind: str) -> None:
    """The plain and the model's gate agree on ``data``: verdict, reason, detail, values."""
    plain, model = Gate(scenario, plain_bulk=True), Gate(scenario)
    got, want = plain.check(topic, data, kind), model.check(topic, data, kind)
    assert plain.skipped == model.skipped, data[:300]
    assert (got is None) == (want is None), data[:300]
    assert _values(got) == _values(want), data[:300]


def test_a_model_with_a_rule_msgspec_cannot_carry_is_refused() -> None:
    class Bounded(BaseModel):
        x: int = Field(le=3)

    class Checked(BaseModel):
        x: int

        @field_validator("x")
        @classmethod
        def small(cls, v: int) -> int:
            return v

    with pytest.raises(TypeError, match=r"Bounded.x: Le\(le=3\) has no msgspec form here"):
        struct_of(Bounded)
    with pytest.raises(TypeError, match="Checked has a validator msgspec cannot apply"):
        struct_of(Checked)


def test_every_forgery_is_refused_alike(paper: Scenario) -> None:
    kinds = {
        keys.netem_decision(RUN): "decision",
        keys.leader_estimate_out(RUN): "leader_estimate",
        keys.metrics(RUN): "metrics",
    }
    for key, data in forgeries(RUN, paper, epoch=7):
        _both(paper, key, data, kinds.get(key, "agent_state"))


# Values near each field's type: what orjson and the model could read differently.
_NUMBERS = st.one_of(
    st.floats(allow_nan=False, allow_infinity=False),
    st.integers(-(2**70), 2**70),
    st.booleans(),
    st.none(),
    st.sampled_from(["1.5", "x", "", "state", "pass", "formation"]),
)
_FLOATS = st.lists(
    st.one_of(st.floats(allow_nan=False, allow_infinity=False), st.integers(-(2**70), 2**70)),
    max_size=3,
)
_ANY = st.one_of(_NUMBERS, _FLOATS, st.lists(_NUMBERS, max_size=3))


def _mutated(draw: Any, good: dict[str, Any]) -> dict[str, Any]:
    out = dict(good)
    for name in draw(st.lists(st.sampled_from([*good, "extra"]), max_size=2)):
        if draw(st.booleans()):
            out[name] = draw(_ANY)
        else:
            out.pop(name, None)
    return out


@st.composite
def states(draw: Any) -> bytes:
    agent = draw(st.sampled_from([1, 2, 3, 99]))
    good = {
        "run_id": RUN,
        "sender": draw(st.sampled_from(["agent/1", "pool/1", "agent/2", "leader"])),
        "seq": draw(st.integers(-1, 3)),
        "epoch": draw(st.integers(-2, 60)),
        "stamp_ns": 5,
        "kind": "state",
        "agent": agent,
        "position": draw(st.lists(st.one_of(st.floats(), st.integers()), min_size=1, max_size=3)),
        "substituted": [
            {"neighbour": draw(st.integers(0, 4)), "value": draw(_FLOATS)}
            for _ in range(draw(st.integers(0, 2)))
        ],
    }
    if draw(st.booleans()):
        good["heading"] = draw(st.one_of(st.floats(allow_nan=False), st.integers(-3, 3)))
    body = _mutated(draw, good)
    subs = body.get("substituted")
    if isinstance(subs, list) and subs and isinstance(subs[0], dict) and draw(st.booleans()):
        body["substituted"][0] = _mutated(draw, body["substituted"][0])
    text = json.dumps(body, allow_nan=True)
    if draw(st.booleans()):  # a duplicate key, which both read as the last
        text = text[:-1] + ', "agent": ' + str(draw(st.integers(0, 3))) + "}"
    return text.encode()


@st.composite
def batches(draw: Any) -> bytes:
    def judgement() -> dict[str, Any]:
        good = {
            "verdict": draw(st.sampled_from(["pass", "drop", "delayed"])),
            "delay_ms": draw(st.floats(allow_nan=False, allow_infinity=False)),
            "queue": draw(st.one_of(st.none(), st.just("radio"))),
        }
        return _mutated(draw, good) if draw(st.integers(0, 4)) == 0 else good

    judgements = [judgement() for _ in range(draw(st.integers(0, 3)))]
    count = draw(st.integers(0, 4))
    records = {
        "source": draw(st.lists(st.integers(0, 4), min_size=count, max_size=count)),
        "target": draw(st.lists(st.integers(0, 4), min_size=count, max_size=count)),
        "epoch": draw(st.lists(st.integers(-1, 60), min_size=count, max_size=count)),
        "seq": [1] * count,
        # an index past the judgements now and then
        "judgement": draw(
            st.lists(st.integers(0, len(judgements)), min_size=count, max_size=count)
        ),
    }
    if draw(st.integers(0, 4)) == 0:  # a column of another length
        records[draw(st.sampled_from(sorted(records)))].append(0)
    good = {
        "run_id": RUN,
        "sender": draw(st.sampled_from(["netem", "agent/1"])),
        "seq": 0,
        "epoch": 3,
        "stamp_ns": 5,
        "kind": "decisions",
        "phase": draw(st.sampled_from(["state", "report", "estimate"])),
        "judgements": judgements,
        "records": _mutated(draw, records) if draw(st.integers(0, 4)) == 0 else records,
    }
    body = _mutated(draw, good) if draw(st.integers(0, 3)) == 0 else good
    return json.dumps(body, allow_nan=True).encode()


@settings(
    max_examples=300,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@given(data=states())
def test_a_state_is_judged_alike_by_both_paths(paper: Scenario, data: bytes) -> None:
    _both(paper, keys.agent_state(RUN, 1), data, "agent_state")


@settings(
    max_examples=200,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@given(data=batches())
def test_a_decision_batch_is_judged_alike_by_both_paths(paper: Scenario, data: bytes) -> None:
    _both(paper, keys.netem_decision(RUN), data, "decision")


@pytest.mark.parametrize(
    "data",
    [
        b'{"run_id":"synthetic","sender":"agent/1","seq":0,"epoch":1,"stamp_ns":0,"agent":1,'
        b'"position":[1e400,0.0]}',  # past a double: orjson refuses, the model reads inf
        b'{"run_id":"synthetic","sender":"agent/1","seq":0,"epoch":1,"stamp_ns":0,"agent":1,'
        b'"position":[1,2]}',  # ints where floats are due: the model converts them
        b'{"run_id":"\\ud800","sender":"agent/1","seq":0,"epoch":1,"stamp_ns":0,"agent":1,'
        b'"position":[1.0,2.0]}',  # a lone surrogate
        b'{"run_id":"synthetic","sender":"agent/1","seq":18446744073709551616,"epoch":1,'
        b'"stamp_ns":0,"agent":1,"position":[1.0,2.0]}',  # past 64 bits
    ],
)
def test_what_orjson_cannot_vouch_for_goes_to_the_model(paper: Scenario, data: bytes) -> None:
    _both(paper, keys.agent_state(RUN, 1), data, "agent_state")


def _same(a: Any, b: Any, name: str) -> None:
    if isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape, name
        assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), name
    elif dataclasses.is_dataclass(a) and not isinstance(a, type):
        for f in dataclasses.fields(a):
            if f.compare:  # not another form of the same values (Decisions.coded)
                _same(getattr(a, f.name), getattr(b, f.name), f"{name}.{f.name}")
    elif hasattr(a, "model_dump_json"):
        assert a.model_dump_json() == b.model_dump_json(), name
    else:
        assert a == b, name


@pytest.fixture(scope="module")
def forged_run(tmp_path_factory: Any, sim_results: dict[str, Any], synth: Any) -> Path:
    """The ``hold`` run with every forgery at epoch 7, in chunks of 4 kB (many chunks)."""
    result = sim_results["hold"]
    bad = forgeries(synth.RUN, result.scenario, epoch=7)
    inject = [(key, data, None, 7 * EPOCH_NS + 50 + m) for m, (key, data) in enumerate(bad)]
    path = tmp_path_factory.mktemp("bulk") / "run.mcap"
    synth.write(path, result, inject=inject, chunk_size=4096)
    return path


def test_the_bulk_path_reads_the_run_the_model_path_reads(forged_run: Path) -> None:
    bulk, model = decode_run(forged_run, bulk=True), decode_run(forged_run, bulk=False)
    assert bulk.recorded.skipped.total == len(forgeries(RUN, bulk.scenario))
    _same(bulk, model, "run")
    assert bulk.decisions is not None and model.decisions is not None
    assert bulk.decisions.coded.keys() == {
        "phase",
        "link_class",
        "verdict",
        "model",
        "state",
        "queue",
    }
    for column, (codes, values) in bulk.decisions.coded.items():
        assert np.array_equal(values[codes], getattr(model.decisions, column)), column


def test_chunks_are_read_in_the_reader_s_file_order(forged_run: Path) -> None:
    with open(forged_run, "rb") as f:
        want = [(c.id, m) for _, c, m in make_reader(f).iter_messages(log_time_order=False)]
    with open_recording(forged_run) as (_, summary):
        got = [(c.id, m) for _, c, m in file_order(forged_run, summary)]
    assert len(summary.chunk_indexes) > 10
    assert got == want


@pytest.mark.parametrize("compression", ["lz4", "none"])
def test_chunks_of_each_compression_are_read_in_the_reader_s_file_order(
    tmp_path: Path, sim_results: dict[str, Any], synth: Any, compression: str
) -> None:
    """zstd chunks are decompressed here (the test above); the others by the library."""
    path = tmp_path / "run.mcap"
    synth.write(path, sim_results["hold"], chunk_size=4096, compression=compression)
    with open(path, "rb") as f:
        want = [(c.id, m) for _, c, m in make_reader(f).iter_messages(log_time_order=False)]
    with open_recording(path) as (_, summary):
        got = [(c.id, m) for _, c, m in file_order(path, summary)]
        assert {c.compression for c in summary.chunk_indexes} == {
            "" if compression == "none" else compression
        }
    assert got == want


def test_a_record_past_its_chunk_is_refused() -> None:
    with pytest.raises(ChunkError, match="a record of 99 bytes at byte 0 of 12"):
        list(chunk_messages(bytes([5]) + (99).to_bytes(8, "little") + b"abc"))


def test_a_short_message_or_a_cut_header_is_refused() -> None:
    message = bytes([5]) + (24).to_bytes(8, "little") + bytes(24)  # 22 bytes of head, 2 of data
    assert chunk_messages(message) == [(0, 0, 0, 0, b"\x00\x00")]
    short = bytes([5]) + (3).to_bytes(8, "little") + b"abc"  # shorter than a message's head
    for tail in (b"", message):
        with pytest.raises(ChunkError, match="a message record of 3 bytes"):
            chunk_messages(message + short + tail)
    with pytest.raises(ChunkError, match="a record header cut at byte 33 of 37"):
        chunk_messages(message + b"\x05abc")


def test_delivery_keeps_the_last_record_of_a_link_and_epoch() -> None:
    links = np.array([[1, 2], [2, 1], [0, 1]])
    rows = [  # epoch, source, target, verdict: (1, 2) at 0 passes, then a later drop
        (0, 1, 2, "pass"),
        (0, 2, 1, "drop"),
        (0, 1, 2, "drop"),
        (1, 1, 2, "pass"),
        (1, 3, 1, "pass"),  # no such link
        (5, 2, 1, "pass"),  # past the count
        (1, 2, 1, "pass"),
    ]
    columns: dict[str, list[Any]] = {
        "epoch": [r[0] for r in rows],
        "phase": ["state"] * len(rows),
        "link_class": ["formation"] * len(rows),
        "source": [r[1] for r in rows],
        "target": [r[2] for r in rows],
        "seq": [0] * len(rows),
        "verdict": [r[3] for r in rows],
        "delay_epochs": [0] * len(rows),
        "delay_ms": [0.0] * len(rows),
        "model": [""] * len(rows),
        "state": [""] * len(rows),
        "queue": [None] * len(rows),
        "queue_depth": [None] * len(rows),
        "sojourn_ms": [None] * len(rows),
    }
    delivered, decided = Decisions.of_columns(columns).delivery(links, 2)
    assert delivered.tolist() == [[False, False, False], [True, True, False]]
    assert decided.tolist() == [[True, True, False], [True, True, False]]


def test_the_recorder_s_own_bulk_messages_take_the_plain_path(
    sim_results: dict[str, Any], synth: Any
) -> None:
    gate = Gate(sim_results["hold"].scenario, plain_bulk=True)
    for key, data, _, _ in synth.traffic(sim_results["hold"])[:200]:
        kind = {keys.netem_decision(RUN): "decision"}.get(key, "agent_state")
        if "estimate" not in key:
            assert isinstance(gate.check(key, data, kind), msgspec.Struct), key


@st.composite
def good_states(draw: Any, scenario: Scenario) -> tuple[str, bytes]:
    """A state the gate passes (on its own): its agent's key, substitutions on real links."""
    links = [(int(a), int(b)) for a, b in scenario.directed_links]
    agent = draw(st.sampled_from(sorted({b for _, b in links})))
    into = [a for a, b in links if b == agent]
    body = {
        "run_id": RUN,
        "sender": draw(st.sampled_from([f"agent/{agent}", "pool/1"])),
        "seq": 0,
        "epoch": draw(st.integers(0, 3)),
        "stamp_ns": 5,
        "agent": agent,
        "position": draw(st.lists(st.floats(-9, 9), min_size=2, max_size=2)),
        "substituted": [
            {"neighbour": draw(st.sampled_from(into)), "value": [1.5, -2.0], "fallback": fb}
            for fb in draw(st.lists(st.booleans(), max_size=2))
        ],
    }
    if draw(st.booleans()):
        body["heading"] = draw(st.floats(-3, 3))
    return keys.agent_state(RUN, agent), json.dumps(body).encode()


_DEFECTS: dict[str, Any] = {  # one thing wrong in a good state
    "epoch": [-1, 60],
    "agent": [1, 7],
    "sender": ["agent/9", "leader", "pool/6"],
    "position": [[1.0], [1.0, 2.0, 3.0]],
    "velocity": [[1.0], [0.5, 0.5]],
    "substituted": [
        [{"neighbour": 0, "value": [1.0, 2.0]}],
        [{"neighbour": 7, "value": [1.0, 2.0]}],
        [{"neighbour": 1, "value": [1.0]}],
        [{"neighbour": 3, "value": [1.0, 2.0]}, {"neighbour": 6, "value": [1.0, 2.0]}],
    ],
    "saturated": [2],
}


@st.composite
def near_good_states(draw: Any, scenario: Scenario) -> tuple[str, bytes]:
    topic, data = draw(good_states(scenario))
    body = json.loads(data)
    field = draw(st.sampled_from(sorted(_DEFECTS)))
    body[field] = draw(st.sampled_from(_DEFECTS[field]))
    return topic, json.dumps(body).encode()


@st.composite
def chunks_of_states(draw: Any, scenario: Scenario) -> list[tuple[str, bytes]]:
    """Mostly good states, now and then a doubtful one, a repeat or a conflicting repeat."""
    out = []
    for _ in range(draw(st.integers(1, 6))):
        pick = draw(st.integers(0, 9))
        if pick == 0:
            out.append((keys.agent_state(RUN, 1), draw(states())))
        elif pick in (2, 3):
            out.append(draw(near_good_states(scenario)))
        elif pick == 1 and out:
            out.append(draw(st.sampled_from(out)))  # the same message again
        else:
            out.append(draw(good_states(scenario)))
    return out


@settings(
    max_examples=60,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@given(data=st.data())
def test_a_chunk_of_states_is_judged_as_the_gate_judges_each(paper: Scenario, data: Any) -> None:
    earlier = data.draw(chunks_of_states(paper))  # what the gates remember already
    chunk = data.draw(chunks_of_states(paper))
    batch, model = Gate(paper, plain_bulk=True), Gate(paper)
    for topic, payload in earlier:
        batch.check(topic, payload, "agent_state")
        model.check(topic, payload, "agent_state")
    block = judge_states(batch, [t for t, _ in chunk], [p for _, p in chunk])
    if block is None:  # the reader's way: the chunk through the gate, one by one
        for topic, payload in chunk:
            batch.check(topic, payload, "agent_state")
    passed = [m for m in (model.check(t, p, "agent_state") for t, p in chunk) if m is not None]
    assert (batch.skipped, batch.passed, batch.seen) == (model.skipped, model.passed, model.seen)
    if block is not None:
        assert len(passed) == len(chunk)
        _same(block, StateBlock.of_rows(passed, paper.dimension), "block")


_GOOD_STATE = {  # agent 2 of the paper scenario: links into it from 1, 3 and 4
    "run_id": RUN, "sender": "agent/2", "seq": 0, "epoch": 1, "stamp_ns": 0, "agent": 2,
    "position": [1.0, 2.0], "substituted": [{"neighbour": 3, "value": [0.5, 0.5]}],
}  # fmt: skip


@pytest.mark.parametrize(
    "defect",
    [
        {"epoch": -1},  # the model takes −1 (a status before the run), the gate does not
        {"epoch": 51},
        {"agent": 3},
        {"agent": 2**63},  # past 63 bits
        {"sender": "agent/3"},
        {"sender": "pool/3"},  # a pool is named by its first agent: 3 cannot hold 2
        {"position": [1.0]},
        {"velocity": [1.0]},
        {"substituted": [{"neighbour": 5, "value": [1.0, 2.0]}]},  # no link 5 -> 2
        {"substituted": [{"neighbour": 2, "value": [1.0, 2.0]}]},  # itself
        {"substituted": [{"neighbour": 6, "value": [1.0, 2.0]}]},  # no agent 6
        {"substituted": [{"neighbour": 1, "value": [1.0]}]},
        {"position": [1.0, 2.0], "kind": "report"},
    ],
)
def test_a_chunk_with_one_doubtful_state_is_judged_one_by_one(
    paper: Scenario, defect: dict[str, Any]
) -> None:
    topic = keys.agent_state(RUN, 2)
    good = json.dumps(_GOOD_STATE).encode()
    bad = json.dumps({**_GOOD_STATE, "epoch": 2, **defect}).encode()  # another key and epoch
    assert Gate(paper).check(topic, good) is not None
    assert Gate(paper).check(topic, bad) is None
    gate = Gate(paper, plain_bulk=True)
    assert judge_states(gate, [topic, topic], [good, bad]) is None
    assert (gate.passed, gate.seen) == ({}, {})
    assert judge_states(gate, [topic], [good]) is not None
    assert (gate.passed["agent_state"], len(gate.seen)) == (1, 1)


def test_a_state_unlike_the_one_before_it_is_judged_one_by_one(paper: Scenario) -> None:
    topic = keys.agent_state(RUN, 2)
    good = json.dumps(_GOOD_STATE).encode()
    gate = Gate(paper, plain_bulk=True)
    assert judge_states(gate, [topic], [good]) is not None
    other = json.dumps({**_GOOD_STATE, "position": [1.5, 2.0]}).encode()
    assert judge_states(gate, [topic], [other]) is None  # a conflict, for the gate to count
    assert judge_states(gate, [topic, topic], [other, other]) is None
    assert gate.passed["agent_state"] == 1
    fresh = Gate(paper, plain_bulk=True)  # the two in one chunk
    assert judge_states(fresh, [topic, topic], [good, other]) is None
    assert (fresh.passed, fresh.seen) == ({}, {})


def _estimate(scenario: Scenario, **changes: Any) -> bytes:
    n = scenario.n
    edges = [[int(a), int(b)] for a, b in scenario.edge_array]
    body = {
        "run_id": RUN, "sender": "leader", "seq": 0, "epoch": 2, "stamp_ns": 0,
        "kind": "estimate", "positions": [[0.5, 1.0]] * (n - 1) + [None],
        "covariances": [[[1.0, 0.0], [0.0, 1.0]]] * (n - 1) + [None],
        "observable": [True] * (n - 1) + [False], "tree": edges[:2],
        "healthy": [edges[0][::-1], *edges[1:]], "components": 1, "rigidity_rank": 3,
        "rigid": True, "x_ref": [0.0, 0.0], "v_ref": [0.0, 0.0], "reports_received": n,
    }  # fmt: skip
    return json.dumps({**body, **changes}).encode()


@pytest.mark.parametrize(
    "changes",
    [
        {},
        {"components": 1.0},  # a float for an int: the model converts it
        {"rigid": 1},  # an int for a bool
        {"positions": [[1, 2]] * 5},  # ints for floats, and too few
        {"tree": [[1, 99]]},  # no such edge
        {"healthy": [[2, 1, 3]]},  # not a pair
        {"covariances": [[[1.0, 0.0]]] * 6},  # one row where two are due
        {"x_ref": [1e400, 0.0]},  # past a double
        {"reports_received": 2**64},  # past 64 bits
        {"extra": 1},
    ],
)
def test_an_estimate_is_judged_alike_by_both_paths(paper: Scenario, changes: Any) -> None:
    _both(paper, keys.leader_estimate_out(RUN), _estimate(paper, **changes), "leader_estimate")


@pytest.mark.parametrize(
    "changes",
    [
        {},
        {"positions": [[1.0, 2.0]] * 5},  # too few
        {"positions": [[1.0, "x"]] * 6},
        {"formation_error_m": None, "shape_error_m": 2},
        {"out": [0, 99]},
    ],
)
def test_metrics_are_judged_alike_by_both_paths(paper: Scenario, changes: Any) -> None:
    body = {
        "run_id": RUN, "sender": "recorder", "seq": 0, "epoch": 2, "stamp_ns": 0,
        "kind": "metrics", "formation_error_m": 0.5, "shape_error_m": 0.25,
        "positions": [[1.0, 2.0]] * paper.n,
    }  # fmt: skip
    data = json.dumps({**body, **changes}).encode()
    _both(paper, keys.metrics(RUN), data, "metrics")
