"""Analysis never trusts the wire: forged and malformed recorded messages are skipped and counted.

A synthetic recording of a simulated run with :func:`testkit.forgeries.forgeries` mixed in
(the same set the live test puts on a real run's keys): every reader gives the numbers of
the clean run and counts each forgery once, on its channel.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from formation import keys
from formation.codec import encode
from formation.messages import (
    AgentEstimate,
    Bundle,
    CoordinationState,
    DeliveredPacket,
    Delivery,
    DeliveryBatch,
    TokenReport,
)
from recorder import read_run
from recorder.playback.player import Replayer
from recorder.reading.reader import describe
from recorder.reading.trust import CONFLICT, FORGED, INVALID, OUT_OF_RANGE, UNKNOWN_KEY, Gate
from recorder.reporting.report import write_report
from testkit.forgeries import forgeries

EPOCH_NS = 1_000_000_000


@pytest.fixture
def forged(tmp_path: Path, sim_results: dict[str, Any], synth: Any) -> tuple[Path, Any, list]:
    """A recording of the simulated ``hold`` run with every forgery received at epoch 7."""
    result = sim_results["hold"]
    bad = forgeries(synth.RUN, result.scenario, epoch=7)
    inject = [(key, data, None, 7 * EPOCH_NS + 50 + m) for m, (key, data) in enumerate(bad)]
    path = tmp_path / "run" / "run.mcap"
    synth.write(path, result, inject=inject)
    return path, result, bad


def test_forgeries_do_not_change_the_numbers_and_are_counted(forged: tuple) -> None:
    path, result, bad = forged
    run = read_run(path)
    assert np.array_equal(run.positions, result.positions)  # no [42, 42], no crash on "x"
    for name in ("delivered", "tree", "healthy", "components", "rigidity_rank"):
        assert np.array_equal(getattr(run, name), getattr(result, name)), name
    np.testing.assert_array_equal(run.formation_error, result.formation_error)
    # the recorder's own metrics were derived from trusted states only: no gap
    np.testing.assert_array_equal(run.recorded.formation_error, result.formation_error)
    skipped = run.recorded.skipped
    assert skipped.total == len(bad)
    expected: dict[str, int] = {}
    for key, _ in bad:
        expected[key] = expected.get(key, 0) + 1
    assert skipped.by_channel() == dict(sorted(expected.items()))
    reasons = skipped.by_reason()
    assert set(reasons) == {INVALID, FORGED, OUT_OF_RANGE, UNKNOWN_KEY}, reasons


def test_report_and_info_state_the_skips(forged: tuple) -> None:
    path, result, bad = forged
    report = write_report(path)
    (summary,) = json.loads((path.parent / "summary.json").read_text())
    assert summary["skipped"]["total"] == len(bad)
    assert summary["recorded_metrics_max_gap_m"] == 0.0
    assert summary["peak_formation_error_m"] == float(np.nanmax(result.formation_error))
    text = report.read_text()
    assert "## Messages not trusted" in text and f": {len(bad)} (" in text
    assert f"`{keys.agent_state('synthetic', 1)}`" in text
    info = describe(path)
    assert info.skipped.total == len(bad)
    assert sum(info.drops.values()) == summary["drops"]["1->2"] + summary["drops"]["2->1"]


def test_formation_report_and_info_exit_0_on_a_forged_file(forged: tuple) -> None:
    path, _, bad = forged
    for cmd in (["report", str(path)], ["info", str(path), "--json"]):
        proc = subprocess.run(
            [sys.executable, "-m", "testbed.cli", *cmd], capture_output=True, text=True, timeout=120
        )
        assert proc.returncode == 0, proc.stderr
        assert "Traceback" not in proc.stderr
    assert json.loads(proc.stdout.splitlines()[-1])["skipped"]["total"] == len(bad)


def test_replay_publishes_only_trusted_messages(forged: tuple) -> None:
    path, _, bad = forged
    replayer = Replayer(path, rate=1e9)
    published: list[str] = []
    state = replayer.run(lambda key, data, att: published.append(key), threading.Event())
    scene_key = keys.scene("synthetic")
    # liveliness is never replayed; of the rest, exactly the forgeries are held back
    assert state.skipped == sum(1 for k, _ in bad if "/alive/" not in k)
    assert published.count(scene_key) == len(read_run(path).positions)


def test_a_different_second_message_of_an_epoch_is_a_conflict(paper: Any) -> None:
    gate = Gate(paper)
    key = keys.agent_state("r", 1)

    def state(x: float) -> bytes:
        return encode(
            CoordinationState(run_id="r", sender="agent/1", seq=3, epoch=3, stamp_ns=1, agent=1,
                              position=[x, 0.0])
        )  # fmt: skip

    assert gate.check(key, state(1.0)) is not None
    assert gate.check(key, state(1.0)) is not None  # a republished final state is no fault
    assert gate.check(key, state(2.0)) is None
    assert gate.skipped.by_reason() == {CONFLICT: 1}


@pytest.mark.parametrize("mode", ["lockstep", "realtime"])
def test_several_deliveries_of_an_epoch_are_a_conflict_in_lockstep_only(
    paper: Any, mode: str
) -> None:
    """Lockstep: one delivery per receiver, phase and epoch; realtime: one per netem wake-up."""
    gate = Gate(paper.with_overrides(runtime={"mode": mode, "realtime_period_s": 0.05}))
    key = keys.inbox("r", 2, "state")

    def delivery(source: int) -> bytes:
        packet = DeliveredPacket(source=source, seq=3, sent_epoch=3, message="{}")
        return encode(Delivery(run_id="r", sender="netem", seq=source, epoch=3, stamp_ns=1,
                               receiver=2, phase="state", packets=[packet], lost=[]))  # fmt: skip

    assert gate.check(key, delivery(1)) is not None
    second = gate.check(key, delivery(3))
    assert (second is None) == (mode == "lockstep")
    assert gate.skipped.by_reason() == ({CONFLICT: 1} if mode == "lockstep" else {})


def test_pooled_agents_own_their_ids(paper: Any) -> None:
    for sender, agent, ok in (("pool/1", 3, True), ("pool/4", 3, False), ("agent/3", 3, True)):
        body = CoordinationState(run_id="r", sender=sender, seq=0, epoch=0, stamp_ns=1,
                                 agent=agent, position=[0.0, 0.0])  # fmt: skip
        got = Gate(paper).check(keys.agent_state("r", agent), encode(body))
        assert (got is not None) == ok, sender


def test_a_pools_batch_is_checked_as_its_deliveries_and_may_come_several_times(
    paper: Any,
) -> None:
    gate = Gate(paper)
    key = keys.inbox_pool("r", 2, "state")

    def batch(
        pool: int = 2,
        receivers: tuple[int, ...] = (2, 3),
        sender: str = "netem",
        sources: tuple[int, ...] = (1, 4),
        carried: list[list[int]] | None = None,
        own: bool = False,
    ) -> bytes:
        table = [DeliveredPacket(source=s, seq=3, sent_epoch=3, message="{}") for s in sources]
        deliveries = [
            Delivery(run_id="r", sender="netem", seq=0, epoch=3, stamp_ns=1, receiver=r,
                     phase="state", packets=table[:1] if own else [], lost=[])
            for r in receivers
        ]  # fmt: skip
        carried = [[0, 1]] * len(receivers) if carried is None else carried
        return encode(DeliveryBatch(run_id="r", sender=sender, seq=0, epoch=3, stamp_ns=1,
                                    pool=pool, phase="state", packets=table,
                                    deliveries=deliveries, carried=carried))  # fmt: skip

    assert gate.check(key, batch()) is not None
    assert gate.check(key, batch(receivers=(4,))) is not None  # netem's second batch of the epoch
    assert gate.check(key, batch(pool=1)) is None  # another pool's
    assert gate.check(key, batch(receivers=(1,))) is None  # an agent before the pool's first
    assert gate.check(key, batch(receivers=(9,))) is None  # no such agent
    assert gate.check(key, batch(sender="agent/2")) is None
    assert gate.check(key, b'{"kind": "delivery_batch"}') is None
    assert gate.skipped.by_reason() == {FORGED: 3, OUT_OF_RANGE: 1, INVALID: 1}
    assert gate.check(key, batch(sources=(1, 99))) is None  # a packet from no agent
    assert gate.check(key, batch(carried=[[0, 2], [1]])) is None  # an index past the table
    assert gate.check(key, batch(carried=[[-1], [1]])) is None
    assert gate.check(key, batch(carried=[[0]])) is None  # a column shorter than the other
    assert gate.check(key, batch(own=True)) is None  # packets outside the table
    assert gate.skipped.by_reason() == {FORGED: 3, OUT_OF_RANGE: 4, INVALID: 3}


def test_a_pools_batch_recorded_before_its_packet_table_is_read_as_its_deliveries(
    paper: Any,
) -> None:
    gate = Gate(paper)
    key = keys.inbox_pool("r", 2, "state")

    def batch(receiver: int) -> bytes:
        packet = DeliveredPacket(source=1, seq=3, sent_epoch=3, message="{}")
        delivery = Delivery(run_id="r", sender="netem", seq=0, epoch=3, stamp_ns=1,
                            receiver=receiver, phase="state", packets=[packet], lost=[])  # fmt: skip
        body = DeliveryBatch(run_id="r", sender="netem", seq=0, epoch=3, stamp_ns=1, pool=2,
                             phase="state", deliveries=[delivery]).model_dump()  # fmt: skip
        del body["packets"], body["carried"]
        return json.dumps(body).encode()

    assert gate.check(key, batch(2)) is not None
    assert gate.check(key, batch(1)) is None  # an agent before the pool's first
    assert gate.skipped.by_reason() == {FORGED: 1}


def test_the_leaders_bundle_is_checked_part_by_part(paper: Any) -> None:
    gate = Gate(paper)
    key = keys.leader_estimates("r")

    def part(agent: int, seq: int = 0, epoch: int = 3, v_ref: float = 0.0) -> dict[str, Any]:
        est = AgentEstimate(run_id="r", sender="leader", seq=seq, epoch=epoch, stamp_ns=1,
                            agent=agent, neighbours=[], positions=[], v_ref=[v_ref, 0.0])  # fmt: skip
        return {"agent": agent, "seq": 0, "message": est.model_dump_json()}

    def bundle(*parts: dict[str, Any], epoch: int = 3, sender: str = "leader") -> bytes:
        return encode(Bundle(run_id="r", sender=sender, seq=epoch, epoch=epoch, stamp_ns=1,
                             phase="estimate", parts=parts))  # fmt: skip

    assert gate.check(key, bundle(part(1), part(2))) is not None
    assert gate.check(key, bundle(part(1), epoch=4, sender="agent/1")) is None
    assert gate.check(key, bundle(part(1), part(2, seq=5), epoch=5)) is None  # seq not the part's
    assert gate.check(key, bundle(part(1, epoch=3), epoch=6)) is None  # another epoch's part
    assert gate.check(key, bundle(part(1), {**part(2), "agent": 3}, epoch=7)) is None
    bad = {**part(1), "message": part(1)["message"].replace('"v_ref"', '"v"')}
    assert gate.check(key, bundle(bad, epoch=8)) is None
    assert gate.check(key, bundle(part(1, v_ref=float("nan"), epoch=9), epoch=9)) is None
    assert gate.skipped.by_reason() == {FORGED: 4, INVALID: 2}


def test_a_pools_report_bundle_is_checked_part_by_part(paper: Any) -> None:
    gate = Gate(paper)
    key = keys.pool_bundle("r", 2, "report")

    def part(agent: int, sender: str = "pool/2", epoch: int = 3) -> dict[str, Any]:
        report = TokenReport(run_id="r", sender=sender, seq=0, epoch=epoch, stamp_ns=1,
                             agent=agent, measurements=[])  # fmt: skip
        return {"agent": agent, "seq": 0, "message": report.model_dump_json()}

    def bundle(*parts: dict[str, Any], epoch: int = 3, sender: str = "pool/2") -> bytes:
        return encode(Bundle(run_id="r", sender=sender, seq=epoch, epoch=epoch, stamp_ns=1,
                             phase="report", parts=parts))  # fmt: skip

    assert gate.check(key, bundle(part(2), part(3))) is not None
    assert gate.check(key, bundle(part(2, epoch=4), epoch=4, sender="pool/1")) is None
    assert gate.check(key, bundle(part(1, sender="pool/1", epoch=5), epoch=5)) is None
    assert gate.check(key, bundle(part(2, epoch=6), part(9, epoch=6), epoch=6)) is None
    assert gate.check(key, bundle(part(2, epoch=3), epoch=7)) is None  # another epoch's part
    assert gate.skipped.by_reason() == {FORGED: 3, OUT_OF_RANGE: 1}
