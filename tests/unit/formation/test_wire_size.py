"""Nominal packet sizes: the wire models' JSON of a lossless epoch, the same in every process."""

from __future__ import annotations

import numpy as np

from formation.codec import encode
from formation.messages import AgentEstimate, CoordinationState, Measurement, TokenReport
from formation.scenario import Scenario
from formation.wire_size import NOMINAL_FLOAT, NOMINAL_RUN_ID, NOMINAL_STAMP_NS, Kind, WireSizes


def test_sizes_are_the_encoded_messages(paper: Scenario) -> None:
    sizes = WireSizes(paper)
    head = {"run_id": NOMINAL_RUN_ID, "seq": 10, "epoch": 10, "stamp_ns": NOMINAL_STAMP_NS}
    vec = [NOMINAL_FLOAT, NOMINAL_FLOAT]
    nbrs = paper.in_neighbours[2]
    state = CoordinationState(**head, sender="agent/3", agent=3, position=vec)
    report = TokenReport(
        **head,
        sender="agent/3",
        agent=3,
        measurements=[Measurement(neighbour=j, token=1, z=vec) for j in nbrs],
    )
    estimate = AgentEstimate(
        **head, sender="leader", agent=3, neighbours=nbrs, positions=[vec] * len(nbrs), v_ref=vec
    )
    assert sizes.payload_bytes("state", 3, 42) == len(encode(state))
    assert sizes.payload_bytes("report", 3, 42) == len(encode(report))
    assert sizes.payload_bytes("estimate", 3, 42) == len(encode(estimate))


def test_sizes_grow_with_the_epochs_digits_and_the_in_degree(paper: Scenario) -> None:
    sizes = WireSizes(paper)
    assert sizes.payload_bytes("state", 1, 9) + 2 == sizes.payload_bytes("state", 1, 10)
    degree = {i: len(paper.in_neighbours[i - 1]) for i in range(1, paper.n + 1)}
    lo, hi = min(degree, key=degree.__getitem__), max(degree, key=degree.__getitem__)
    assert degree[lo] < degree[hi]
    assert sizes.payload_bytes("report", lo, 5) < sizes.payload_bytes("report", hi, 5)


def test_a_double_integrators_state_carries_its_velocity(paper: Scenario) -> None:
    double = paper.with_overrides(control={**paper.control.model_dump(), "dynamics": "double"})
    assert WireSizes(double).payload_bytes("state", 2, 3) > WireSizes(paper).payload_bytes(
        "state", 2, 3
    )


def test_sizes_of_many_epochs_at_once_are_each_ones(paper: Scenario) -> None:
    sizes = WireSizes(paper)
    epochs = np.array([0, 1, 9, 10, 11, 99, 100, 999, 1000, 12345, 10**6], dtype=np.int64)
    cases: list[tuple[Kind, int]] = [("state", 1), ("report", 3), ("estimate", 5)]
    for kind, agent in cases:
        got = sizes.payload_bytes_of(kind, agent, epochs).tolist()
        assert got == [sizes.payload_bytes(kind, agent, int(e)) for e in epochs]
