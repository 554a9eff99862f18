"""Replaying a recording over Zenoh on 127.0.0.1: its queryable, and a run's leader inputs
replayed into a fresh leader.

The test process is a Zenoh peer listening on a free port; the replay and the leader connect
to it in client mode, as the launcher starts them (``testkit/src/testkit/zenoh_peer.py``).
Readiness is a liveliness token or a queryable's reply, never a fixed sleep; every process is
ended by PID in a ``finally``. The recorder itself: ``test_recorder_live.py``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader

from formation import keys
from formation.codec import read_attachment
from formation.messages import CoordinationState
from formation.scenario import Scenario
from recorder.playback.player import control_key
from recorder.reading.reader import validate
from recorder.recording.writer import RecordingWriter
from testkit.zenoh_peer import WAIT_S, peer, process, state, token_seen, wait_for

pytestmark = pytest.mark.integration
REPLAY_CLI = (
    "import argparse, sys\n"
    "from testbed.cli.replay import register\n"
    "p = argparse.ArgumentParser(); register(p.add_subparsers(dest='command'))\n"
    "a = p.parse_args(sys.argv[1:]); sys.exit(a.func(a))\n"
)


def test_replay_publishes_the_recording_and_obeys_its_queryable(tmp_path: Path) -> None:
    """20 recorded states 50 ms apart, replayed at rate 2 under a new prefix, started by ``resume``."""
    path, log = tmp_path / "run.mcap", tmp_path / "replay.log"
    rec = RecordingWriter(path)
    for k in range(20):
        rec.write(
            keys.agent_state("orig", 1 + k % 2),
            state("orig", 1 + k % 2, k, [float(k), 0.0]),
            10**15 + k * 50_000_000,
        )
    rec.close()
    got: list[tuple[float, str, bytes, Any]] = []
    with peer() as (session, endpoint):
        sub = session.declare_subscriber(
            "formation/again/**",
            lambda s: got.append(
                (
                    time.monotonic(),
                    str(s.key_expr),
                    s.payload.to_bytes(),
                    read_attachment(s.attachment.to_bytes() if s.attachment else None),
                )
            ),
        )
        args = [
            "-c",
            REPLAY_CLI,
            "replay",
            str(path),
            "--paused",
            "--rate",
            "2",
            "--prefix",
            "formation/again",
            "--mode",
            "client",
            "--connect",
            endpoint,
        ]
        with process(*args, log=log) as proc:

            def control(command: str) -> dict[str, Any]:
                for reply in session.get(
                    control_key("formation/again"),
                    payload=json.dumps({"command": command}),
                    timeout=2.0,
                ):
                    if reply.ok is not None:
                        return dict(json.loads(reply.ok.payload.to_bytes()))
                return {}

            wait_for(
                lambda: control("status").get("paused") is True, proc, "the replay's queryable", log
            )
            assert got == []
            assert control("resume")["paused"] is False
            wait_for(
                lambda: len(got) == 20 and proc.poll() is not None,
                proc if len(got) < 20 else None,
                "20 messages",
                log,
            )
            assert proc.returncode == 0, log.read_text()
        sub.undeclare()
    assert [k for _, k, _, _ in got] == [
        f"formation/again/agent/{1 + k % 2}/state" for k in range(20)
    ]
    assert [CoordinationState.model_validate_json(p).position[0] for _, _, p, _ in got] == [
        float(k) for k in range(20)
    ]
    assert [a for *_, a in got] == [(k, k, 1 + k % 2) for k in range(20)]
    assert got[-1][0] - got[0][0] >= 19 * 0.05 / 2 - 0.01


def non_trivial_png(path: Path) -> None:
    from matplotlib.image import imread

    pixels = imread(path)
    assert path.stat().st_size > 10_000 and pixels.shape[0] > 300, path
    assert pixels[..., :3].std() > 0.05, f"{path.name} is nearly uniform"


def recorded_estimates(path: Path, run_id: str) -> dict[int, dict[str, Any]]:
    with open(path, "rb") as f:
        messages = make_reader(f).iter_messages(topics=[keys.leader_estimate_out(run_id)])
        return {m["epoch"]: m for m in (json.loads(msg.data) for _, _, msg in messages)}


@pytest.mark.slow
def test_default_run_report_and_replay_into_a_fresh_leader(
    paper: Scenario, runs_dir: Path, tmp_path: Path
) -> None:
    """``formation run`` records; the report matches the simulator; the leader's recorded inputs,
    replayed into a fresh leader under another run id, give the same estimates (same inputs, same outputs)."""
    from recorder import read_run
    from recorder.reporting.report import FIGURES, write_report
    from testbed.runtime.launcher import launch
    from testbed.sim.simulate import simulate

    outcome = launch(paper, strategy="estimate", runs_dir=runs_dir, record=True)
    mcap = outcome.run_dir / "run.mcap"
    check = validate(mcap)
    assert check.failures == 0, check.examples

    # Nothing lost at the recorder: per channel, what the services say they sent.
    from collections import Counter

    from mcap.reader import make_reader

    with mcap.open("rb") as f:
        recorded = Counter(ch.topic for _, ch, _ in make_reader(f).iter_messages())
    assert outcome.sent, "the services report what they sent in their final status"
    for key, count in outcome.sent.items():
        assert recorded[key] == count, key
    report = write_report(mcap)
    for name in FIGURES:
        non_trivial_png(report.parent / f"{name}.png")
    (summary,) = json.loads((report.parent / "summary.json").read_text())
    sim = simulate(paper, strategy="estimate")
    run = read_run(mcap)
    assert run.positions.shape == sim.positions.shape
    assert summary["final_formation_error_m"] == pytest.approx(
        float(sim.formation_error[-1]), abs=1e-9
    )
    assert summary["final_formation_error_m"] == float(run.formation_error[-1])
    assert summary["recorded_metrics_max_gap_m"] == 0.0
    assert summary["drops"] == {"1->2": paper.epochs - 1, "2->1": paper.epochs - 1}
    assert summary["nees_mean"] == pytest.approx(float(sim.nees_values.mean()), rel=1e-9)
    # Substitution errors from the substitutes the agents published, against the recorded truth.
    order = np.lexsort(
        (
            sim.substitutions.neighbour,
            sim.substitutions.agent,
            sim.substitution_epochs,
        )
    )
    assert (
        run.substitution_errors.shape
        == sim.substitution_errors.shape
        == (2 * (paper.epochs - 1), 2)
    )
    np.testing.assert_allclose(run.substitution_errors, sim.substitution_errors[order], atol=1e-9)
    assert summary["substitutions"] == 2 * (paper.epochs - 1)

    live = recorded_estimates(mcap, outcome.run_id)
    assert sorted(live) == list(range(paper.epochs))
    fresh, log, replay_log = "replayed", tmp_path / "leader.log", tmp_path / "replay.log"
    got: dict[int, dict[str, Any]] = {}
    with peer() as (session, endpoint):
        tokens = [
            session.liveliness().declare_token(keys.alive(fresh, "netem", 0)),
            session.liveliness().declare_token(keys.start(fresh)),
        ]
        sub = session.declare_subscriber(
            keys.leader_estimate_out(fresh),
            lambda s: got.update({(m := json.loads(s.payload.to_bytes()))["epoch"]: m}),
        )
        leader = [
            "-m",
            "leader",
            "--scenario",
            str(outcome.run_dir / "scenario.toml"),
            "--run-id",
            fresh,
            "--mode",
            "client",
            "--connect",
            endpoint,
        ]
        with (
            token_seen(session, keys.alive(fresh, "leader", 0)) as ready,
            process(*leader, log=log) as proc,
        ):
            wait_for(ready, proc, "the fresh leader's token", log)
            topics = keys.inbox(outcome.run_id, keys.LEADER_ENDPOINT, "report")
            replay = [
                "-c",
                REPLAY_CLI,
                "replay",
                str(mcap),
                "--rate",
                "20",
                "--topics",
                topics,
                "--prefix",
                keys.prefix(fresh),
                "--mode",
                "client",
                "--connect",
                endpoint,
            ]
            with process(*replay, log=replay_log) as rp:
                wait_for(
                    lambda: len(got) == paper.epochs, proc, "the fresh leader's estimates", log
                )
                assert rp.wait(timeout=WAIT_S) == 0, replay_log.read_text()
            assert proc.wait(timeout=WAIT_S) == 0, log.read_text()
        sub.undeclare()
        for token in tokens:
            token.undeclare()
    same = (
        "positions",
        "covariances",
        "observable",
        "tree",
        "healthy",
        "components",
        "rigidity_rank",
        "rigid",
        "x_ref",
        "v_ref",
        "reports_received",
    )
    for k in range(paper.epochs):
        assert {f: got[k][f] for f in same} == {f: live[k][f] for f in same}, f"epoch {k}"
