"""Nominal packet sizes: the wire models' JSON of a lossless epoch, the same in every process."""

from __future__ import annotations

from formation.codec import encode
from formation.messages import AgentEstimate, CoordinationState, Measurement, TokenReport
from formation.scenario import Scenario
from formation.wire_size import NOMINAL_FLOAT, NOMINAL_RUN_ID, NOMINAL_STAMP_NS, WireSizes


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
