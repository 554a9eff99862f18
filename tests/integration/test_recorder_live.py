"""The recorder as a real process over Zenoh on 127.0.0.1: counts, schemas, kill -9, replay.

The test process is a Zenoh peer listening on a free port; the recorder (and the
replay) connect to it in client mode, as the launcher starts them. Readiness is a
liveliness token or a queryable's reply, never a fixed sleep; every process is
ended by PID in a ``finally``.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh
from mcap.reader import make_reader
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader

from formation import keys
from formation.codec import attachment, encode, read_attachment
from formation.errors import RecordingError
from formation.messages import CoordinationState, Decision, DecisionBatch, Status
from formation.scenario import Scenario
from formation.zenoh_config import session_config
from recorder.reader import describe, validate
from recorder.recover import recover
from recorder.replay import control_key
from recorder.writer import RecordingWriter

pytestmark = pytest.mark.integration
ROOT = Path(__file__).resolve().parents[2]
HOST = "127.0.0.1"
WAIT_S = 30.0  # longest wait for any readiness [s]
REPLAY_CLI = (
    "import argparse, sys\n"
    "from testbed.cli.recorder import register\n"
    "p = argparse.ArgumentParser(); register(p.add_subparsers(dest='command'))\n"
    "a = p.parse_args(sys.argv[1:]); sys.exit(a.func(a))\n"
)


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((HOST, 0))
        return int(s.getsockname()[1])


def child_env() -> dict[str, str]:
    env = dict(os.environ)
    return env


@contextmanager
def peer() -> Iterator[tuple[Any, str]]:
    """This test's Zenoh peer, listening on loopback; yields (session, endpoint)."""
    endpoint = f"tcp/{HOST}:{free_port()}"
    session: Any = zenoh.open(session_config("peer", None, endpoint))
    try:
        yield session, endpoint
    finally:
        session.close()


@contextmanager
def process(*args: str, log: Path) -> Iterator[subprocess.Popen[bytes]]:
    """A child process; killed by PID at the end if it is still running."""
    with open(log, "wb") as out:
        proc = subprocess.Popen(
            [sys.executable, *args], env=child_env(), stdout=out, stderr=subprocess.STDOUT
        )
        try:
            yield proc
        finally:
            if proc.poll() is None:
                os.kill(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)


def wait_for(
    condition: Callable[[], bool], proc: subprocess.Popen[bytes] | None, what: str, log: Path
) -> None:
    deadline = time.monotonic() + WAIT_S
    while not condition():
        if proc is not None and proc.poll() is not None:
            pytest.fail(
                f"process exited ({proc.returncode}) while waiting for {what}:\n{log.read_text()[-3000:]}"
            )
        if time.monotonic() > deadline:
            pytest.fail(f"timed out waiting for {what}:\n{log.read_text()[-3000:]}")
        time.sleep(0.01)


@contextmanager
def token_seen(session: Any, key: str) -> Iterator[Callable[[], bool]]:
    """A condition that turns true once the liveliness token ``key`` exists (history included)."""
    seen = threading.Event()

    def on_token(sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            seen.set()

    sub = session.liveliness().declare_subscriber(key, on_token, history=True)
    try:
        yield seen.is_set
    finally:
        sub.undeclare()


def start_recorder(run_id: str, out: Path, endpoint: str, *extra: str) -> list[str]:
    return [
        "-m",
        "recorder",
        "--run-id",
        run_id,
        "--out",
        str(out),
        "--mode",
        "client",
        "--connect",
        endpoint,
        "--no-live",
        *extra,
    ]


def recorded_counts(session: Any, run_id: str) -> dict[str, int]:
    """The recorder's flush barrier: its counts per key of everything it has received."""
    for reply in session.get(keys.flush(run_id), timeout=5.0):
        if reply.ok is not None:
            return dict(json.loads(reply.ok.payload.to_bytes()))
    return {}


def state(run_id: str, i: int, k: int, x: list[float]) -> bytes:
    return encode(
        CoordinationState(
            run_id=run_id,
            sender=f"agent/{i}",
            seq=k,
            epoch=k,
            stamp_ns=time.monotonic_ns(),
            agent=i,
            position=x,
        )
    )


def test_recorder_keeps_every_message_with_its_schema(
    tmp_path: Path, paper: Scenario, paper_path: Path
) -> None:
    """Messages on 14 keys from another process: counts equal, all validate, scenario stored."""
    run_id, out, log = "rec-count", tmp_path / "out", tmp_path / "recorder.log"
    sent: Counter[str] = Counter()
    epochs, bulk = 4, 3000
    with (
        peer() as (session, endpoint),
        process(
            *start_recorder(run_id, out, endpoint, "--scenario", str(paper_path)), log=log
        ) as proc,
    ):
        with token_seen(session, keys.alive(run_id, "recorder", 0)) as ready:
            wait_for(ready, proc, "the recorder's token", log)
        pubs: dict[str, Any] = {}

        def put(key: str, payload: bytes, att: bytes | None = None) -> None:
            if key not in pubs:
                pubs[key] = session.declare_publisher(
                    key, congestion_control=zenoh.CongestionControl.BLOCK
                )
            pubs[key].put(payload, attachment=att)
            sent[key] += 1

        for k in range(epochs):
            for i in range(1, paper.n + 1):
                put(
                    keys.agent_state(run_id, i),
                    state(run_id, i, k, (paper.offsets[i - 1] + 0.01 * k).tolist()),
                    attachment(k, k, i),
                )
            decisions = [
                Decision(source=1, target=2, link_class="formation", epoch=k, seq=k, verdict="drop")
            ]
            put(
                keys.netem_decision(run_id),
                encode(
                    DecisionBatch(
                        run_id=run_id,
                        sender="netem",
                        seq=k,
                        epoch=k,
                        stamp_ns=1,
                        phase="state",
                        decisions=decisions,
                    )
                ),
            )
            put(
                keys.status(run_id, "agent", 1),
                encode(
                    Status(
                        run_id=run_id,
                        sender="agent/1",
                        seq=k,
                        epoch=k,
                        stamp_ns=1,
                        role="agent",
                        state="running",
                    )
                ),
            )
        for n in range(bulk):  # a burst on the delivered-state keys
            i, j = (1, 3) if n % 2 else (3, 1)
            put(
                keys.link_state(run_id, i, j), state(run_id, i, n, [0.5, 0.25]), attachment(n, n, i)
            )
        put(f"{keys.prefix(run_id)}/custom/thing", b'{"free": "form"}')
        wait_for(
            lambda: all(recorded_counts(session, run_id).get(k, 0) >= v for k, v in sent.items()),
            proc,
            "the flush barrier",
            log,
        )
        os.kill(proc.pid, signal.SIGTERM)
        assert proc.wait(timeout=WAIT_S) == 0, log.read_text()

    info = describe(out / "run.mcap")
    counts = {c.topic: c.messages for c in info.channels}
    assert {k: counts.get(k) for k in sent} == dict(sent)
    assert counts[keys.metrics(run_id)] == epochs  # every epoch complete → metrics and a scene
    assert counts[keys.scene(run_id)] == epochs
    assert counts[keys.alive(run_id, "recorder", 0)] >= 1
    assert info.drops == {"formation 1->2": epochs}
    assert info.scenario is not None and info.scenario.to_toml() == paper.to_toml()
    assert info.metadata["recorder_stats"]["dropped"] == "0"
    check = validate(out / "run.mcap")
    assert check.failures == 0, check.examples
    assert check.by_schema["foxglove.SceneUpdate"] == epochs
    assert check.by_schema["unknown"] == 1
    assert (out / "scenario.toml").read_text() == paper.to_toml()


def readable(path: Path) -> list[tuple[Channel, Message]]:
    """The messages of complete chunks of a file that may be cut anywhere."""
    channels: dict[int, Channel] = {}
    got = []
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f).records:
                if isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Message):
                    got.append((channels[record.channel_id], record))
        except Exception:  # any torn record ends the readable prefix (EndOfFile, zstd, CRC, ...)
            pass
    return got


def test_kill_9_loses_at_most_the_open_chunk(tmp_path: Path) -> None:
    """N1 = 2000 messages are on disk before the kill (the test waits for them); N2 = 3000 more
    are sent just before SIGKILL. ``recover`` keeps exactly seq 0 .. c − 1 with c ≥ N1: every
    complete chunk, no gap; only the chunk open at the kill is lost."""
    run_id, out, log = "rec-kill", tmp_path / "out", tmp_path / "recorder.log"
    key, n1, n2 = keys.link_state(run_id, 2, 4), 2000, 3000
    with (
        peer() as (session, endpoint),
        process(
            *start_recorder(
                run_id, out, endpoint, "--chunk-interval", "0.05", "--chunk-size", "16K"
            ),
            log=log,
        ) as proc,
    ):
        with token_seen(session, keys.alive(run_id, "recorder", 0)) as ready:
            wait_for(ready, proc, "the recorder's token", log)
        pub = session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
        payloads = [state(run_id, 2, n, [1.0, 2.0]) for n in range(n1 + n2)]
        for n in range(n1):
            pub.put(payloads[n], attachment=attachment(n, n, 2))
        on_disk = lambda: sum(1 for ch, _ in readable(out / "run.mcap") if ch.topic == key) >= n1  # noqa: E731
        wait_for(on_disk, proc, f"{n1} messages on disk", log)
        for n in range(n1, n1 + n2):
            pub.put(payloads[n], attachment=attachment(n, n, 2))
        os.kill(proc.pid, signal.SIGKILL)
        assert proc.wait(timeout=WAIT_S) == -signal.SIGKILL

    with pytest.raises(RecordingError, match=r"run\.mcap: truncated MCAP file"):
        describe(out / "run.mcap")
    result = recover(out / "run.mcap")
    with open(result.target, "rb") as f:
        seqs = [
            m.sequence
            for _, ch, m in make_reader(f, validate_crcs=True).iter_messages()
            if ch.topic == key
        ]
    assert len(seqs) >= n1, result.describe()
    assert seqs == list(range(len(seqs)))  # a prefix of what was sent, no gap
    assert len(seqs) <= n1 + n2
    assert [m.data for ch, m in readable(result.target) if ch.topic == key] == payloads[: len(seqs)]


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
    from recorder.report import FIGURES, write_report
    from recorder.rundata import read_run
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
            sim.extra["substitution_senders"],
            sim.extra["substitution_receivers"],
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
            topics = keys.inbox(outcome.run_id, keys.LEADER, "report")
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
