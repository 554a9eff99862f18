"""The closed network on 127.0.0.1: authentication and access control with `formation keys`' files.

A router (``python -m testbed.runtime.router``) with the generated access control and
password file, a real recorder process with its own credentials, and sessions in
this process acting as agents, netem, the leader, the operator and intruders.
Zenoh exposes no counter of the messages its access control refuses (its
decisions show only in trace-level logs), so refusals are counted on the
receiving side: every attempt is tallied, and an
attempt is refused when it reached neither the recording nor a subscribing agent.
"""

from __future__ import annotations

import json
import shutil
import threading
import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import zenoh
from mcap.reader import make_reader

from formation import keys
from testbed.deploy import security
from testbed.runtime.processes import ProcessGroup, free_port, wait_for_port

pytestmark = pytest.mark.integration

HOST = "127.0.0.1"
RUN = "secure-run"
N = 20  # attempts per key


@dataclass
class Network:
    endpoint: str
    keyset: security.KeySet
    group: ProcessGroup
    tmp: Path

    def session(self, user: str | None) -> zenoh.Session:
        path = self.keyset.config(user) if user else None
        return zenoh.open(security.client_session_config(self.endpoint, path))


def _start_router(
    tmp: Path, keyset: security.KeySet, tls: bool = False
) -> tuple[ProcessGroup, str]:
    group = ProcessGroup(tmp / "logs")
    port = free_port(HOST)
    endpoint = f"{'tls' if tls else 'tcp'}/{HOST}:{port}"
    group.start(
        "router", "testbed.runtime.router", "--listen", endpoint, "--passwords", str(keyset.passwords_file),
        env={"ZENOH_CONFIG": str(keyset.router_config)},
    )  # fmt: skip
    wait_for_port(HOST, port, 10.0)
    return group, endpoint


@pytest.fixture
def network(tmp_path: Path) -> Iterator[Network]:
    keyset = security.generate(tmp_path / "keys", n_agents=5)
    group, endpoint = _start_router(tmp_path, keyset)
    try:
        yield Network(endpoint, keyset, group, tmp_path)
    finally:
        group.stop_all()  # by PID, also when the test failed
        assert all(c.proc.poll() is not None for c in group.children)


def test_sessions_without_valid_credentials_are_refused(network: Network) -> None:
    attempts = {
        "no credentials": None,
        "unknown user": ("intruder", "x"),
        "wrong password": ("agent-1", "x"),
    }
    refused = Counter[str]()
    for what, cred in attempts.items():
        conf = security.client_session_config(network.endpoint)
        if cred is not None:
            conf.insert_json5(
                "transport/auth/usrpwd", json.dumps({"user": cred[0], "password": cred[1]})
            )
        try:
            zenoh.open(conf).close()
        except zenoh.ZError:
            refused[what] += 1
    assert refused == dict.fromkeys(attempts, 1)


def test_each_user_publishes_only_its_own_keys(network: Network) -> None:
    """Forged keys reach neither a subscribing agent nor the recording; allowed ones arrive, all N."""
    ks = keys
    allowed = {
        "agent-1": [ks.agent_state(RUN, 1), ks.agent_report(RUN, 1)],
        "netem": [ks.link_state(RUN, 1, 2), ks.inbox(RUN, 2, "state"), ks.netem_decision(RUN)],
        "leader": [ks.leader_estimate_out(RUN)],
    }
    forged = {
        "agent-1": [ks.agent_state(RUN, 2), ks.agent_report(RUN, 3), ks.link_state(RUN, 1, 2),
                    ks.leader_estimate_out(RUN), ks.inbox(RUN, 2, "state"), ks.status(RUN, "agent", 2),
                    ks.netem_decision(RUN)],
        "netem": [ks.agent_state(RUN, 1), ks.leader_estimate_out(RUN)],
        "leader": [ks.link_estimate(RUN, 1), ks.agent_report(RUN, 3)],
        "operator": [ks.agent_state(RUN, 4), ks.metrics(RUN)],
        "recorder": [ks.agent_state(RUN, 5)],
    }  # fmt: skip
    operator = network.session("operator")
    agent2 = network.session("agent-2")  # an agent listening to everything of the run
    sessions: dict[str, zenoh.Session] = {}
    heard: Counter[tuple[str, str]] = Counter()  # (key, sender) at agent 2
    tokens_seen: set[str] = set()
    lock = threading.Lock()

    def on_sample(sample: zenoh.Sample) -> None:
        with lock:
            heard[str(sample.key_expr), json.loads(sample.payload.to_bytes())["by"]] += 1

    def on_token(sample: zenoh.Sample) -> None:
        with lock:
            tokens_seen.add(str(sample.key_expr))

    keep: list[object] = [
        agent2.declare_subscriber(keys.everything(RUN), on_sample),
        agent2.liveliness().declare_subscriber(keys.alive_all(RUN), on_token, history=True),
    ]
    rec_dir = network.tmp / "recording"
    recorder = network.group.start(
        "recorder", "recorder", "--run-id", RUN, "--out", str(rec_dir), "--mode", "client",
        "--connect", network.endpoint, env={"ZENOH_CONFIG": str(network.keyset.config("recorder"))},
    )  # fmt: skip
    try:
        _wait(
            lambda: keys.alive(RUN, "recorder", 0) in tokens_seen, "the recorder's token", network
        )
        attempts: Counter[tuple[str, str]] = Counter()  # (key, sender) of every forged message
        # an unauthenticated peer: it may open, but nothing it says gets in
        try:
            intruder = zenoh.open(_peer_config(network.endpoint))
        except zenoh.ZError:
            intruder = None
        for _ in range(N):
            attempts[keys.agent_state(RUN, 3), "intruder"] += 1
            if intruder is not None:
                intruder.put(keys.agent_state(RUN, 3), _payload("intruder"))
        for user in forged:
            s = sessions[user] = network.session(user)
            # forged liveliness first: an agent posing as agent 3, or as netem's start
            if user == "agent-1":
                keep += [s.liveliness().declare_token(keys.alive(RUN, "agent", 3)),
                         s.liveliness().declare_token(keys.start(RUN)),
                         s.declare_queryable(keys.netem_config(RUN), lambda q: q.reply(q.key_expr, b"forged")),
                         s.declare_queryable(keys.netem_final(RUN), lambda q: q.reply(q.key_expr, b"forged"))]  # fmt: skip
            if user == "netem":
                keep.append(
                    s.declare_queryable(
                        keys.netem_final(RUN), lambda q: q.reply(q.key_expr, b"netem")
                    )
                )
            for key in forged[user]:
                for _ in range(N):
                    s.put(key, _payload(user))
                    attempts[key, user] += 1
            for key in allowed.get(user, []):  # after the forged ones: their arrival is the barrier
                for _ in range(N):
                    s.put(key, _payload(user))
            if user == "agent-1":
                keep.append(s.liveliness().declare_token(keys.alive(RUN, "agent", 1)))
        legit = Counter({(k, user): N for user, ks_ in allowed.items() for k in ks_})
        _wait(
            lambda: all(heard[k] >= n for k, n in legit.items()),
            "the allowed messages at agent 2",
            network,
        )
        _wait(lambda: keys.alive(RUN, "agent", 1) in tokens_seen, "agent 1's own token", network)
        counts = _recorder_counts(
            operator, lambda c: all(c.get(k, 0) >= n for (k, _), n in legit.items())
        )
        replies = list(operator.get(keys.netem_config(RUN), timeout=1.0))
        final: list[bytes] = []  # the leader asks netem for what it lacks (netem/final)

        def ask_final() -> bool:
            final[:] = [
                r.ok.payload.to_bytes()
                for r in sessions["leader"].get(keys.netem_final(RUN), timeout=1.0)
                if r.ok
            ]
            return bool(final)

        _wait(ask_final, "netem's answer on netem/final", network)
    finally:
        for s in [*sessions.values()]:
            s.close()
        code = network.group.stop(recorder, timeout_s=30)
        agent2.close()
        operator.close()
    assert code == 0
    recorded = _mcap_counts(rec_dir / "run.mcap")
    # refused = attempted, minus what reached agent 2, minus what reached the recording
    refused = {f"{k} by {u}": attempts[k, u] - heard[k, u] - recorded[k, u] for k, u in attempts}
    print("refused attempts:", json.dumps(refused, indent=1), "total", sum(refused.values()))
    assert refused == {f"{k} by {u}": n for (k, u), n in attempts.items()}
    only_forged = {k for k, _ in attempts} - {k for k, _ in legit}
    assert all(counts.get(k, 0) == 0 for k in only_forged)  # the recorder's own tally agrees
    assert {k: heard[k] for k in legit} == dict(legit)  # nothing lost of what is allowed
    assert {k: recorded[k] for k in legit} == dict(legit)
    assert keys.alive(RUN, "agent", 3) not in tokens_seen and keys.start(RUN) not in tokens_seen
    assert recorded[keys.alive(RUN, "agent", 3), ""] == 0 and recorded[keys.start(RUN), ""] == 0
    assert recorded[keys.alive(RUN, "agent", 1), ""] >= 1
    assert replies == []  # agent 1's forged netem/config queryable is not reachable
    assert final == [b"netem"]  # netem's netem/final is, agent 1's forged one is not


@pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl command")
def test_tls_links_with_generated_keys(tmp_path: Path) -> None:
    keyset = security.generate(tmp_path / "keys", n_agents=2, tls=True, tls_hosts=[HOST])
    group, endpoint = _start_router(tmp_path, keyset, tls=True)
    try:
        operator = zenoh.open(security.client_session_config(endpoint, keyset.config("operator")))
        got = threading.Event()
        sub = operator.declare_subscriber(keys.agent_state(RUN, 1), lambda s: got.set())
        agent = zenoh.open(security.client_session_config(endpoint, keyset.config("agent-1")))
        deadline = time.monotonic() + 10
        while not got.is_set() and time.monotonic() < deadline:
            agent.put(keys.agent_state(RUN, 1), b"{}")
            got.wait(0.05)
        assert got.is_set()
        # credentials without the CA: the router's certificate is not trusted
        conf = security.client_session_config(endpoint)
        conf.insert_json5(
            "transport/auth/usrpwd",
            json.dumps({"user": "agent-2", "password": keyset.passwords["agent-2"]}),
        )
        with pytest.raises(zenoh.ZError):
            zenoh.open(conf)
        sub.undeclare()
        agent.close()
        operator.close()
    finally:
        group.stop_all()


def _peer_config(endpoint: str) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    return conf


def _wait(cond, what: str, network: Network, timeout_s: float = 15.0) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout_s
    while not cond():
        failed = network.group.failed()
        assert not failed, f"{failed[0].name} exited: {failed[0].tail()}"
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.01)


def _recorder_counts(session: zenoh.Session, done, timeout_s: float = 15.0) -> dict[str, int]:  # type: ignore[no-untyped-def]
    """The recorder's counts per key (a flush barrier), once ``done(counts)`` holds."""
    deadline = time.monotonic() + timeout_s
    counts: dict[str, int] = {}
    while time.monotonic() < deadline:
        for reply in session.get(keys.flush(RUN), timeout=2.0):
            if reply.ok is not None:
                counts = json.loads(reply.ok.payload.to_bytes())
                if done(counts):
                    return counts
    raise AssertionError(f"the recorder's counts never completed: {counts}")


def _payload(sender: str) -> bytes:
    return json.dumps({"by": sender}).encode()


def _mcap_counts(path: Path) -> Counter[tuple[str, str]]:
    """Recorded messages per ``(topic, sender)``; liveliness events have sender ``""``."""
    counts: Counter[tuple[str, str]] = Counter()
    with path.open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
            counts[channel.topic, json.loads(message.data).get("by", "")] += 1
    return counts


def test_rmw_zenoh_robots_and_their_agents_pass_the_closed_router(tmp_path: Path) -> None:
    """``formation keys`` for a scenario with rmw_zenoh bodies (domain 3): the user ``robots``
    sends poses and reads commands; agent 1 commands its robot and reads its pose, and may not
    command robot 2. Every node's liveliness token reaches the other side."""
    pytest.importorskip("rosbags", reason="the ros2 extra")
    from body.rmw_zenoh import RmwZenohNode, pose_cdr, read_pose, read_twist, twist_cdr
    from formation.body import Body, Qos

    body = Body(kind="rmw_zenoh", domain_id=3)
    keyset = security.generate(tmp_path / "keys", n_agents=2, body=body)
    assert security.ROBOTS in keyset.configs
    group, endpoint = _start_router(tmp_path, keyset)
    network = Network(endpoint, keyset, group, tmp_path)
    agent, robots = network.session("agent-1"), network.session(security.ROBOTS)
    try:
        plant = RmwZenohNode(robots, 3, "plant")
        node = RmwZenohNode(agent, 3, "formation_agent_1")
        commands: dict[int, list[float]] = {1: [], 2: []}
        for i in (1, 2):
            plant.subscribe(f"/robot{i}/cmd_vel", "geometry_msgs/msg/Twist", Qos(),
                            lambda cdr, i=i: commands[i].append(read_twist(cdr)[0][0]))  # fmt: skip
        poses: list[float] = []
        node.subscribe("/robot1/pose", "geometry_msgs/msg/PoseStamped", Qos(),
                       lambda cdr: poses.append(read_pose("geometry_msgs/msg/PoseStamped", cdr)[0][0]))  # fmt: skip
        command = node.publisher("/robot1/cmd_vel", "geometry_msgs/msg/Twist", Qos())
        forged = node.publisher("/robot2/cmd_vel", "geometry_msgs/msg/Twist", Qos())
        pose = plant.publisher("/robot1/pose", "geometry_msgs/msg/PoseStamped", Qos())

        def exchange() -> bool:  # until the router has both sides' subscriptions
            command(twist_cdr([0.5, 0.0]))
            forged(twist_cdr([9.0, 0.0]))
            pose(pose_cdr("geometry_msgs/msg/PoseStamped", [1.5, 0.0], 1, "world"))
            return bool(commands[1]) and bool(poses)

        _wait(exchange, "a command and a pose through the router", network)
        for _ in range(N):
            forged(twist_cdr([9.0, 0.0]))
        command(twist_cdr([0.5, 0.0]))
        _wait(lambda: len(commands[1]) >= 2, "the last command", network)
        assert set(commands[1]) == {0.5} and set(poses) == {1.5}
        assert commands[2] == []  # agent 1 may not command robot 2
        seen = [str(r.ok.key_expr) for r in robots.liveliness().get("@ros2_lv/3/**") if r.ok]
        assert any("formation_agent_1" in k for k in seen), seen
        plant.close()
        node.close()
    finally:
        agent.close()
        robots.close()
        group.stop_all()
