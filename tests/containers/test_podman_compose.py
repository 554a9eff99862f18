"""The unchanged compose.yaml under podman-compose, loopback only, against a native run.

Run by ``make compose-test`` (after ``deploy/podman.sh engine base build``), which sets
``PODMAN_COMPOSE`` and ``CONTAINERS_CONF`` and ``FORMATION_REQUIRE_CONTAINERS=1``: without
podman-compose these tests then fail; elsewhere (``make test``) they skip. The services run
from the image on the host's network, each service name on its own 127.0.0.N
(``deploy/compose.loopback.yaml``); ``up``, wait for netem to exit, ``down``. The recording
must hold every sender's count and every epoch, the SDK's protobuf SceneUpdate schema, and
equal a native ``formation run`` of the same scenario and seed; a second run starts the
router 10 s after every other service. What the services write in ``./runs`` must belong to
the user they run as, a non-root one (as root, :data:`NON_ROOT`).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import yaml
from foxglove.messages import SceneUpdate
from mcap.reader import make_reader

from formation import keys
from formation.scenario import Scenario
from recorder.analysis.rundata import read_run

pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.containers]

ROOT = Path(__file__).resolve().parents[2]
COMPOSE = ROOT / "compose.yaml"
OVERRIDE = ROOT / "deploy" / "compose.loopback.yaml"
PODMAN_COMPOSE = os.environ.get("PODMAN_COMPOSE", "")
REQUIRED = os.environ.get("FORMATION_REQUIRE_CONTAINERS", "") == "1"  # set by make compose-test
WAIT_S = 300  # netem's exit; the default scenario takes seconds
DOWN_S = 180  # the recorder's stop_grace_period is 2 min
LATE_S = 10.0  # the router's delay in the start-up test
# As root the services run as this user, not compose's default 1000, so the check also shows
# FORMATION_UID reaching them; the keys and the run directory are handed to it as a user's are.
NON_ROOT = (1001, 1001)


@dataclass(frozen=True)
class Deployment:
    """One compose run's inputs: the environment podman-compose gets and what it should write."""

    doc: dict[str, Any]
    scenario_file: Path
    scenario: Scenario
    run_id: str
    env: dict[str, str]
    owner: int  # the host uid that must own what the services write

    @property
    def project(self) -> str:
        return str(self.doc["name"])

    @property
    def run_dir(self) -> Path:
        return ROOT / "runs" / self.run_id

    @property
    def workers(self) -> list[str]:
        return [n for n in self.doc["services"] if n not in ("router", "recorder")]


def _require_podman() -> None:
    """Skip without podman-compose, or fail when ``FORMATION_REQUIRE_CONTAINERS=1``."""
    missing = [n for n in ("PODMAN_COMPOSE", "CONTAINERS_CONF") if not os.environ.get(n)]
    if missing:
        why = f"{' and '.join(missing)} empty (deploy/podman.sh env)"
    elif not os.access(PODMAN_COMPOSE, os.X_OK):
        why = f"PODMAN_COMPOSE = {PODMAN_COMPOSE!r} is not an executable (deploy/podman.sh engine)"
    elif shutil.which("podman") is None:
        why = "podman is not on PATH (deploy/podman.sh engine)"
    else:
        return
    if REQUIRED:
        pytest.fail(f"FORMATION_REQUIRE_CONTAINERS=1 but {why}")
    pytest.skip(f"needs podman-compose: {why}; run `make compose-test`")


def _run_as() -> tuple[tuple[int, int], int]:
    """The services' uid:gid, and the host uid that must own their files.

    As root the containers would run as root too and an ownership check would show nothing,
    so they run as :data:`NON_ROOT`. Without root, podman is rootless: the container's root is
    the invoking user (README, Deployment).
    """
    if os.getuid() == 0:
        return NON_ROOT, NON_ROOT[0]
    return (0, 0), os.getuid()


@pytest.fixture
def deployment(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Deployment]:
    """Keys and ``runs/<RUN_ID>`` owned by the services' user; the run directory removed after."""
    _require_podman()
    doc = yaml.safe_load(COMPOSE.read_text())
    mount = doc["services"]["netem"]["volumes"][0].split(":")[0]
    scenario_file = (ROOT / mount).resolve()
    (uid, gid), owner = _run_as()
    suffix = "-late" if "late" in request.node.name else ""
    run_id = f"podman{suffix}-{os.getpid()}"
    subprocess.run(
        [sys.executable, "-m", "testbed.cli", "keys", str(tmp_path / "keys"), str(scenario_file)],
        check=True, capture_output=True, timeout=120,
    )  # fmt: skip
    runs = ROOT / "runs"
    made_runs = not runs.exists()
    run_dir = runs / run_id
    run_dir.mkdir(parents=True)  # as a user does before `up`
    if os.getuid() == 0:  # hand the user its keys (0600) and its run directory
        for path in [tmp_path / "keys", *(tmp_path / "keys").rglob("*"), run_dir]:
            os.chown(path, uid, gid)
    env = {
        **os.environ,
        "FORMATION_KEYS": str(tmp_path / "keys"),
        "RUN_ID": run_id,
        "FORMATION_UID": str(uid),
        "FORMATION_GID": str(gid),
    }
    env.pop("FORMATION_RUNS", None)  # the default, ./runs, as a user runs it
    dep = Deployment(doc, scenario_file, Scenario.from_file(scenario_file), run_id, env, owner)
    _compose("down", env=env, timeout_s=DOWN_S)  # leftovers of an interrupted run
    try:
        yield dep
    finally:
        shutil.rmtree(run_dir, ignore_errors=True)
        if made_runs and not any(runs.iterdir()):
            runs.rmdir()


def _compose(*args: str, env: dict[str, str], timeout_s: float) -> subprocess.CompletedProcess[str]:
    argv = [PODMAN_COMPOSE, "-f", str(COMPOSE), "-f", str(OVERRIDE), *args]
    return subprocess.run(
        argv, cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout_s, check=False
    )


def _containers(project: str) -> dict[str, str]:
    """Container name → status line, of the compose project."""
    out = subprocess.run(
        ["podman", "ps", "-a", "--filter", f"label=io.podman.compose.project={project}",
         "--format", "{{.Names}}\t{{.Status}}"],
        capture_output=True, text=True, check=True, timeout=60,
    ).stdout  # fmt: skip
    return dict(line.split("\t", 1) for line in out.splitlines() if "\t" in line)


def _failed(project: str) -> None:
    """Raise, with its log, when a service of the project has exited with an error."""
    failed = {
        n: s for n, s in _containers(project).items() if s.startswith("Exited") and "(0)" not in s
    }
    if failed:
        name = next(iter(failed))
        log = subprocess.run(["podman", "logs", name], capture_output=True, text=True).stderr
        raise AssertionError(f"{failed}; {name}'s log:\n{log[-3000:]}")


def _wait_netem(project: str, timeout_s: float) -> int:
    """netem's exit code; fails early, with its log, when another service fails."""
    netem = f"{project}_netem_1"
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        _failed(project)
        if _containers(project).get(netem, "").startswith("Exited"):
            code = subprocess.run(
                ["podman", "wait", netem], capture_output=True, text=True, check=True, timeout=60
            )
            return int(code.stdout.strip())
        time.sleep(0.2)
    raise AssertionError(f"netem did not exit within {timeout_s} s: {_containers(project)}")


def _recording(path: Path, run_id: str) -> dict[str, Any]:
    """Counts per topic, last status per topic, agents' epochs, schemas; the run id as ``RUN``."""
    counts: Counter[str] = Counter()
    statuses: dict[str, dict[str, Any]] = {}
    epochs: dict[str, set[int]] = {}
    schemas: dict[str, tuple[str, str, bytes]] = {}
    with path.open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
            topic = channel.topic.replace(f"/{run_id}/", "/RUN/", 1)
            counts[topic] += 1
            if schema is not None:
                schemas[topic] = (schema.name, schema.encoding, schema.data)
            if "/status/" in topic:
                statuses[topic] = json.loads(message.data)
            elif topic.endswith("/state") and "/agent/" in topic:
                epochs.setdefault(topic, set()).add(json.loads(message.data)["epoch"])
    return {"counts": counts, "statuses": statuses, "epochs": epochs, "schemas": schemas}


def _check_run(dep: Deployment) -> dict[str, Any]:
    """Every sender's count and every epoch recorded, the SDK's schema, the report, the owner."""
    got = _recording(dep.run_dir / "run.mcap", dep.run_id)
    sent: Counter[str] = Counter()
    for name in dep.workers:
        role, ident = ("agent", int(name[6:])) if name.startswith("agent-") else (name, 0)
        status = got["statuses"][keys.status("RUN", role, ident)]
        assert status["state"] == "done", (name, status)
        sent.update({k.replace(f"/{dep.run_id}/", "/RUN/", 1): v
                     for k, v in status["sent"].items() if "/status/" not in k})  # fmt: skip
    assert sent and all(got["counts"][k] == v for k, v in sent.items()), {
        k: (v, got["counts"][k]) for k, v in sent.items() if got["counts"][k] != v
    }
    assert got["epochs"] == {
        keys.agent_state("RUN", i): set(range(dep.scenario.epochs + 1))
        for i in range(1, dep.scenario.n + 1)
    }
    # the scene in Foxglove's own protobuf schema, from the SDK (the image's pins the checkout's)
    sdk = SceneUpdate.get_schema()
    assert got["schemas"][keys.scene("RUN")] == (sdk.name, "protobuf", bytes(sdk.data))
    # the report, naming host paths
    report = (dep.run_dir / "report.md").read_text()
    assert f"runs/{dep.run_id}/run.mcap" in report and "/app/" not in report
    # everything the services wrote belongs to the user they ran as
    written = list(dep.run_dir.rglob("*"))
    assert written and {p.stat().st_uid for p in written} == {dep.owner}, {
        str(p.relative_to(dep.run_dir)): p.stat().st_uid for p in written
    }
    return got


def test_compose_yaml_under_podman_equals_a_native_run(
    deployment: Deployment, tmp_path: Path
) -> None:
    dep = deployment
    t0 = time.monotonic()
    try:
        up = _compose("up", "-d", env=dep.env, timeout_s=300)
        assert up.returncode == 0, up.stdout[-2000:] + up.stderr[-3000:]
        t_up = time.monotonic()
        assert _wait_netem(dep.project, WAIT_S) == 0
        t_exit = time.monotonic()
    finally:
        down = _compose("down", env=dep.env, timeout_s=DOWN_S)
    t_down = time.monotonic()
    assert down.returncode == 0, down.stderr[-3000:]
    containers = t_down - t0
    got = _check_run(dep)

    # the same scenario and seed, natively
    native_runs = tmp_path / "native"
    t1 = time.monotonic()
    native = subprocess.run(
        [sys.executable, "-m", "testbed.cli", "run", str(dep.scenario_file), "--runs-dir",
         str(native_runs)],
        capture_output=True, text=True, timeout=300, cwd=tmp_path,
    )  # fmt: skip
    native_s = time.monotonic() - t1
    assert native.returncode == 0, native.stderr[-3000:]
    (native_dir,) = [p for p in native_runs.iterdir() if (p / "run.mcap").is_file()]
    mine = _recording(native_dir / "run.mcap", native_dir.name)
    assert set(mine["counts"]) == set(got["counts"])  # the same channels
    ours, theirs = read_run(dep.run_dir / "run.mcap"), read_run(native_dir / "run.mcap")
    assert abs(ours.formation_error[-1] - theirs.formation_error[-1]) <= 1e-9
    print(
        f"\npodman-compose: up {t_up - t0:.1f} s, netem's exit after {t_exit - t_up:.1f} s, "
        f"down {t_down - t_exit:.1f} s: {containers:.1f} s in all; native formation run "
        f"{native_s:.1f} s; final formation error {ours.formation_error[-1]:.6g} m (both); "
        f"files owned by uid {dep.owner}"
    )


def test_router_started_late_under_podman_still_gives_a_complete_run(
    deployment: Deployment,
) -> None:
    """Every service but the router up first; the router 10 s later: the clients retry."""
    dep = deployment
    clients = [n for n in dep.doc["services"] if n != "router"]
    try:
        up = _compose("up", "-d", "--no-deps", *clients, env=dep.env, timeout_s=300)
        assert up.returncode == 0, up.stdout[-2000:] + up.stderr[-3000:]
        t_up = time.monotonic()
        while time.monotonic() - t_up < LATE_S:  # the delay is the test; no one may give up
            _failed(dep.project)
            time.sleep(0.5)
        states = _containers(dep.project)
        assert sorted(states) == sorted(f"{dep.project}_{n}_1" for n in clients), states
        assert all(s.startswith("Up") for s in states.values()), states
        router = _compose("up", "-d", "--no-deps", "router", env=dep.env, timeout_s=120)
        assert router.returncode == 0, router.stdout[-2000:] + router.stderr[-3000:]
        assert _wait_netem(dep.project, WAIT_S) == 0
        # the clients waited for the router; `restart: on-failure` did not start them again
        restarts = subprocess.run(
            ["podman", "inspect", "--format", "{{.Name}} {{.RestartCount}}",
             *(f"{dep.project}_{n}_1" for n in clients)],
            capture_output=True, text=True, check=True, timeout=60,
        ).stdout  # fmt: skip
        assert dict(line.split() for line in restarts.splitlines()) == {
            f"{dep.project}_{n}_1": "0" for n in clients
        }
    finally:
        down = _compose("down", env=dep.env, timeout_s=DOWN_S)
    assert down.returncode == 0, down.stderr[-3000:]
    _check_run(dep)
