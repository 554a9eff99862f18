"""A pooled lockstep run over the batched wire: netem sends each pool one message per phase
and epoch (``inbox/pool/<p>/<phase>``), a pool its agents' states and reports and the leader
its agents' parts as one bundle an epoch, the run equals the simulator to the bit, and the
recording carries the batches with their schemas, passes the trust gate and ``formation info
--validate``, and still gives every agent's states (the bulk reader, the gate's own path and
the recorder's live formation error)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from formation import keys
from formation.scenario import Scenario
from recorder import describe, read_run
from recorder.reading.run import decode_run
from testbed import cli
from testbed.runtime.launcher import launch
from testbed.sim.simulate import simulate

pytestmark = pytest.mark.integration


def test_a_pooled_run_over_batched_deliveries_equals_the_simulator(
    paper: Scenario, runs_dir: Path
) -> None:
    scenario = paper.with_overrides(epochs=12)
    outcome = launch(scenario, runs_dir=runs_dir, pool=2)  # agents 1-3 and 4-5
    np.testing.assert_array_equal(outcome.positions, simulate(scenario).positions)
    assert outcome.malformed == {}
    run = outcome.run_id
    batches = {keys.inbox_pool(run, p, phase) for p in (1, 4) for phase in ("state", "estimate")}
    assert batches <= set(outcome.sent)
    alone = {k for k in outcome.sent if keys.parse(k).kind == "inbox"}
    assert alone == {keys.inbox(run, 0, "report")}  # the leader's, not pooled
    # one batch per pool, phase and epoch
    assert {outcome.sent[k] for k in batches} == {scenario.epochs}
    assert outcome.sent[keys.leader_estimates(run)] == scenario.epochs
    reports = {keys.pool_bundle(run, p, "report") for p in (1, 4)}
    assert {outcome.sent[k] for k in reports} == {scenario.epochs}
    states = {keys.pool_states(run, p) for p in (1, 4)}
    assert {outcome.sent[k] for k in states} == {scenario.epochs + 1}  # x[0] .. x[E]
    one_each = {"leader_estimate_for", "agent_report", "agent_state"}
    assert not [k for k in outcome.sent if keys.parse(k).kind in one_each]

    mcap = outcome.run_dir / "run.mcap"
    info = describe(mcap)
    schemas = {c.topic: c.schema for c in info.channels}
    assert {schemas[k] for k in batches} == {"formation.DeliveryBatch"}
    bundles = {keys.leader_estimates(run), *reports, *states}
    assert {schemas[k] for k in bundles} == {"formation.Bundle"}
    assert not [c for c in info.channels if keys.parse(c.topic).kind == "agent_state"]
    assert info.skipped.total == 0
    assert cli.main(["info", str(mcap), "--validate"]) == 0
    recorded = read_run(mcap)
    np.testing.assert_array_equal(recorded.positions, outcome.positions)
    by_gate = decode_run(mcap, bulk=False)
    np.testing.assert_array_equal(by_gate.positions, outcome.positions)
    assert by_gate.recorded.skipped.total == 0
    np.testing.assert_allclose(recorded.recorded.formation_error, recorded.formation_error)
