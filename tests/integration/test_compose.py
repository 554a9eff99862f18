"""compose.yaml as the source of truth: its services as real processes, each on its own host address.

Nothing about the services is written here: :class:`testkit.loopback.LoopbackDeployment`
parses the file, runs each ``command`` with its ``environment``, maps service names
to ``127.A.B.N`` and container paths to host files. The network is closed as
deployed: credentials from ``formation keys``, the router's access control on.
"""

from __future__ import annotations

import json
import threading
import time
from collections import Counter
from ipaddress import ip_address, ip_network
from pathlib import Path

import pytest
import yaml
import zenoh
from mcap.reader import make_reader

from formation import keys
from formation.scenario import Scenario
from shell.zenoh_config import open_with_retry
from testbed.cli import main as formation
from testbed.deploy import security
from testkit.loopback import LoopbackDeployment

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]
COMPOSE = ROOT / "compose.yaml"
RUN_ID = "compose-test"
LOOPBACK = ip_network("127.0.0.0/8")


def _tcp_sockets() -> list[tuple[str, str, str]]:
    """``(local, remote, state)`` of every IPv4 TCP socket on this machine (``/proc/net/tcp``)."""

    def addr(hex_addr: str) -> str:
        host, port = hex_addr.split(":")
        return f"{ip_address(bytes.fromhex(host)[::-1])}:{int(port, 16)}"

    out = []
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        cols = line.split()
        out.append(
            (
                addr(cols[1]),
                addr(cols[2]),
                {"0A": "listen", "01": "established"}.get(cols[3], cols[3]),
            )
        )
    return out


def _recorded(mcap_path: Path) -> tuple[Counter[str], dict[str, dict], dict[str, set[int]]]:
    """Messages per topic, the last status per topic, and the epochs of each agent's states."""
    counts: Counter[str] = Counter()
    statuses: dict[str, dict] = {}
    epochs: dict[str, set[int]] = {}
    with mcap_path.open("rb") as f:
        reader = make_reader(f)
        for _, channel, message in reader.iter_messages(log_time_order=False):
            counts[channel.topic] += 1
            if "/status/" in channel.topic:
                statuses[channel.topic] = json.loads(message.data)
            elif channel.topic.endswith("/state") and "/agent/" in channel.topic:
                epochs.setdefault(channel.topic, set()).add(json.loads(message.data)["epoch"])
    return counts, statuses, epochs


def _scenario_file(doc: dict) -> Path:
    """The host file bind-mounted as the services' scenario."""
    mounts = [v.split(":") for v in doc["services"]["netem"]["volumes"]]
    return ROOT / next(src for src, target, *_ in mounts if target == "/app/scenario.toml")


def test_compose_services_run_as_separate_hosts_and_record_everything(tmp_path: Path) -> None:
    doc = yaml.safe_load(COMPOSE.read_text())
    scenario_file = _scenario_file(doc)
    scenario = Scenario.from_file(scenario_file)
    assert formation(["keys", str(tmp_path / "keys"), str(scenario_file)]) == 0
    runs = tmp_path / "runs"
    env = {"FORMATION_KEYS": str(tmp_path / "keys"), "FORMATION_RUNS": str(runs), "RUN_ID": RUN_ID}
    workers = [n for n in doc["services"] if n not in ("router", "recorder")]
    with LoopbackDeployment(COMPOSE, tmp_path / "logs", env) as dep:
        addresses = set(dep.addresses.values()) | {dep.host_address}
        assert len(addresses) == len(doc["services"]) + 1
        assert all(ip_address(a) in LOOPBACK for a in addresses)
        subnet = ip_network(f"{dep.host_address}/24", strict=False)
        router = dep.addresses["router"]
        for svc in dep.services:  # every service reaches the others only through the router
            if svc.name == "router":
                continue
            assert svc.env["ZENOH_MODE"] == "client" and "ZENOH_LISTEN" not in svc.env
            assert svc.env["ZENOH_CONNECT"].startswith(f"tcp/{router}:")
        dep.up(timeout_s=30)
        endpoint = dep.bound(doc["services"]["router"]["environment"]["ZENOH_LISTEN"])
        operator = security.client_session_config(endpoint, tmp_path / "keys" / "operator.json5")
        session = open_with_retry(operator, endpoint, 30.0)  # nothing waits for the router
        try:
            started = threading.Event()
            sockets: list[tuple[str, str, str]] = []

            def on_start(sample: zenoh.Sample) -> None:  # every service is connected by now
                if not started.is_set():
                    sockets.extend(_tcp_sockets())
                    started.set()

            token = session.liveliness().declare_subscriber(
                keys.start(RUN_ID), on_start, history=True
            )
            deadline = time.monotonic() + 60
            while not started.wait(0.05):
                dep.check()
                assert time.monotonic() < deadline, "netem never declared the start"
            # from the start: only the router listens, every connection has the router at one
            # end, and every service is connected to it. /proc/net/tcp is not read atomically
            # (a socket table changing under the read can skip lines), so the connections are
            # the union of snapshots, taken until every service is seen or 10 s pass.
            expected = {dep.addresses[n] for n in doc["services"] if n != "router"}
            peers: set[str] = set()
            snapshot_deadline = time.monotonic() + 10
            while True:
                inside = [
                    s for s in sockets
                    if ip_address(s[0].split(":")[0]) in subnet or ip_address(s[1].split(":")[0]) in subnet
                ]  # fmt: skip
                assert {s[0].split(":")[0] for s in inside if s[2] == "listen"} == {router}
                assert all(
                    router in (s[0].split(":")[0], s[1].split(":")[0])
                    for s in inside
                    if s[2] == "established"
                )
                peers |= {
                    s[0].split(":")[0]
                    for s in inside
                    if s[2] == "established" and s[1].startswith(router + ":")
                }
                if expected <= peers or time.monotonic() > snapshot_deadline:
                    break
                time.sleep(0.05)
                sockets = _tcp_sockets()
            assert expected <= peers
            dep.wait_exit(workers, timeout_s=90)
            _flush(session, {keys.status(RUN_ID, *_role(n)) for n in workers})
            token.undeclare()
        finally:
            session.close()
        codes = dep.down()  # docker compose down: the recorder finishes the file and the report
    assert all(svc.child is not None and svc.child.proc.poll() is not None for svc in dep.started)
    assert codes == {**{n: 0 for n in workers}, "recorder": 0, "router": 0}
    run_dir = runs / RUN_ID
    assert (run_dir / "report.md").is_file() and (run_dir / "summary.json").is_file()
    _check_complete(run_dir, scenario, workers)


def test_router_started_late_still_gives_a_complete_run(tmp_path: Path) -> None:
    """The router starts 10 s after every other service: the clients retry until it answers."""
    doc = yaml.safe_load(COMPOSE.read_text())
    scenario_file = _scenario_file(doc)
    scenario = Scenario.from_file(scenario_file)
    assert formation(["keys", str(tmp_path / "keys"), str(scenario_file)]) == 0
    runs = tmp_path / "runs"
    env = {"FORMATION_KEYS": str(tmp_path / "keys"), "FORMATION_RUNS": str(runs), "RUN_ID": RUN_ID}
    workers = [n for n in doc["services"] if n not in ("router", "recorder")]
    with LoopbackDeployment(COMPOSE, tmp_path / "logs", env) as dep:
        t0 = time.monotonic()
        dep.up(timeout_s=30, late={"router": 10.0})
        assert time.monotonic() - t0 >= 10.0
        assert all(dep.service(n).child.proc.poll() is None for n in workers)  # type: ignore[union-attr]
        dep.wait_exit(workers, timeout_s=120)
        codes = dep.down()
    assert codes == {**{n: 0 for n in workers}, "recorder": 0, "router": 0}
    logs = (tmp_path / "logs" / "recorder.log").read_text()
    assert f"report {runs / RUN_ID / 'report.md'}" in logs  # the host's path, not /app/...
    report = (runs / RUN_ID / "report.md").read_text()
    assert report.startswith(f"# {scenario.name}: ")  # the short title of a local run's report
    assert f"`{runs / RUN_ID / 'run.mcap'}`" in report and "/app/" not in report
    _check_complete(runs / RUN_ID, scenario, workers)


def _check_complete(run_dir: Path, scenario: Scenario, workers: list[str]) -> None:
    """Every sender's count recorded, every epoch of every agent, the leader's every estimate."""
    counts, statuses, epochs = _recorded(run_dir / "run.mcap")
    sent: Counter[str] = Counter()
    for name in workers:
        status = statuses[keys.status(RUN_ID, *_role(name))]
        assert status["state"] == "done"
        sent.update({k: v for k, v in status["sent"].items() if "/status/" not in k})
    assert sent and all(counts[k] == v for k, v in sent.items()), {
        k: (v, counts[k]) for k, v in sent.items() if counts[k] != v
    }
    assert {k: e for k, e in epochs.items()} == {
        keys.agent_state(RUN_ID, i): set(range(scenario.epochs + 1))
        for i in range(1, scenario.n + 1)
    }
    assert counts[keys.leader_estimate_out(RUN_ID)] == scenario.epochs


def _role(service: str) -> tuple[str, int]:
    """The role and id under which a compose service publishes its status."""
    if service.startswith("agent-"):
        return "agent", int(service.removeprefix("agent-"))
    return service, 0


def _flush(session: zenoh.Session, status_keys: set[str], timeout_s: float = 15.0) -> None:
    """Wait until the recorder has received every service's final status (each one's last message)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for reply in session.get(keys.flush(RUN_ID), timeout=2.0):
            if reply.ok is not None and status_keys <= set(json.loads(reply.ok.payload.to_bytes())):
                return
    raise AssertionError(
        f"the recorder did not receive {sorted(status_keys)} within {timeout_s:g} s"
    )
