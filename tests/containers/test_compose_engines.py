"""The unchanged compose.yaml under podman-compose and Docker Compose, loopback only.

Each engine's run is checked against a native run of the same scenario and seed.

Run by ``make compose-test`` (after ``deploy/podman.sh`` and ``deploy/docker.sh engine base
build``), which sets each engine's variables (``deploy/<engine>.sh env``) and
``FORMATION_REQUIRE_CONTAINERS`` to the engines that must run: without one of them its tests
then fail; elsewhere (``make test``) they skip. Each test runs once per engine, with the same
checks. The services run from the image on the host's network, each service name on its own
127.0.0.N (``deploy/compose.loopback.yaml``); ``up``, wait for netem to exit, ``down``; under
Docker the README's commands (``up --build -d``, ``wait netem``, ``down``). The recording must
hold every sender's count and every epoch, the SDK's protobuf SceneUpdate schema, and equal a
native ``formation run`` of the same scenario and seed; a second run starts the router 10 s
after every other service. What the services write in ``./runs`` must belong to the user they
run as, a non-root one (as root, :data:`NON_ROOT`).
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

import numpy as np
import pytest
import yaml
from foxglove.messages import SceneUpdate
from mcap.reader import make_reader

from formation import keys
from formation.scenario import Scenario
from recorder import read_run
from testbed.sim.simulate import simulate

pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.containers]

ROOT = Path(__file__).resolve().parents[2]
COMPOSE = ROOT / "compose.yaml"
PLUGINS = ROOT / "compose.plugins.yaml"  # the example plug-ins' scenario, from an image with them
OVERRIDE = ROOT / "deploy" / "compose.loopback.yaml"
# scenarios/robots.toml: every body a ROS 2 robot, the headless plant in the profile ros2
ROBOTS = ROOT / "compose.ros2.yaml"
ROBOTS_OVERRIDE = ROOT / "deploy" / "compose.ros2.loopback.yaml"
# The engines whose tests fail rather than skip when they cannot run (make compose-test).
REQUIRED = os.environ.get("FORMATION_REQUIRE_CONTAINERS", "").split()
WAIT_S = 300  # netem's exit; the default scenario takes seconds
DOWN_S = 180  # the recorder's stop_grace_period is 2 min
LATE_S = 10.0  # the router's delay in the start-up test
# As root the services run as this user, not compose's default 1000, so the check also shows
# FORMATION_UID reaching them; the keys and the run directory are handed to it as a user's are.
NON_ROOT = (1001, 1001)


@dataclass(frozen=True)
class Engine:
    """A container engine and its compose: how to call them, and how they name what they run."""

    name: str
    compose: tuple[str, ...]  # the command, before ``-f``
    cli: str  # ``podman`` or ``docker``
    project_label: str  # the label every container of a compose project carries
    sep: str  # between project, service and index in a container's name
    variables: tuple[str, ...]  # what ``deploy/<name>.sh env`` sets

    def container(self, project: str, service: str) -> str:
        return f"{project}{self.sep}{service}{self.sep}1"

    def missing(self) -> str | None:
        """Why the engine cannot run the test, or None."""
        unset = [n for n in self.variables if not os.environ.get(n)]
        if unset:
            return f"{' and '.join(unset)} empty (deploy/{self.name}.sh env)"
        if shutil.which(self.cli) is None:
            return f"{self.cli} is not on PATH (deploy/{self.name}.sh engine)"
        if not os.access(self.compose[0], os.X_OK) and shutil.which(self.compose[0]) is None:
            return f"{self.compose[0]!r} is not an executable (deploy/{self.name}.sh engine)"
        probe = subprocess.run(
            [*self.compose, "version"], capture_output=True, text=True, timeout=60, check=False
        )
        if probe.returncode != 0:
            return f"`{' '.join(self.compose)} version` failed: {probe.stderr.strip()[-300:]}"
        if self.cli == "docker":
            info = subprocess.run(["docker", "info"], capture_output=True, text=True, timeout=60)
            if info.returncode != 0:
                host = os.environ["DOCKER_HOST"]
                return f"no Docker engine answers on {host}: {info.stderr.strip()[-300:]}"
        return None


ENGINES = [
    Engine(
        name="podman",
        compose=(os.environ.get("PODMAN_COMPOSE", "podman-compose"),),
        cli="podman",
        project_label="io.podman.compose.project",
        sep="_",
        variables=("PODMAN_COMPOSE", "CONTAINERS_CONF"),
    ),
    Engine(
        name="docker",
        compose=("docker", "compose"),
        cli="docker",
        project_label="com.docker.compose.project",
        sep="-",
        variables=("DOCKER_HOST", "DOCKER_CONFIG"),
    ),
]


@dataclass(frozen=True)
class Deployment:
    """One compose run's inputs: the engine, the environment it gets and what it should write."""

    engine: Engine
    compose: Path
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
        return [n for n in self.doc["services"] if n not in ("router", "recorder", "plant")]

    @property
    def files(self) -> list[str]:
        """``-f`` the compose file and its loopback override, and the plant's profile if any."""
        robots = self.compose == ROBOTS
        override = ROBOTS_OVERRIDE if robots else OVERRIDE
        return [
            "-f",
            str(self.compose),
            "-f",
            str(override),
            *(["--profile", "ros2"] if robots else []),
        ]


def _require(engine: Engine) -> None:
    """Skip when the engine cannot run, or fail when ``FORMATION_REQUIRE_CONTAINERS`` names it."""
    why = engine.missing()
    if why is None:
        return
    if engine.name in REQUIRED:
        pytest.fail(f"FORMATION_REQUIRE_CONTAINERS names {engine.name}, but {why}")
    pytest.skip(f"needs {engine.name}: {why}; run `make compose-test`")


def _run_as() -> tuple[tuple[int, int], int]:
    """The services' uid:gid, and the host uid that must own their files.

    As root the containers would run as root too and an ownership check would show nothing,
    so they run as :data:`NON_ROOT`. Without root, podman is rootless: the container's root is
    the invoking user (README, Deployment); Docker's engine runs as root (``deploy/docker.sh``).
    """
    if os.getuid() == 0:
        return NON_ROOT, NON_ROOT[0]
    return (0, 0), os.getuid()


@pytest.fixture(params=ENGINES, ids=[e.name for e in ENGINES])
def engine(request: pytest.FixtureRequest) -> Engine:
    engine: Engine = request.param
    _require(engine)
    return engine


@pytest.fixture
def compose_file(request: pytest.FixtureRequest) -> Path:
    """compose.yaml, unless a test names another (``indirect``)."""
    return getattr(request, "param", COMPOSE)


@pytest.fixture
def deployment(
    engine: Engine, compose_file: Path, request: pytest.FixtureRequest, tmp_path: Path
) -> Iterator[Deployment]:
    """Keys and ``runs/<RUN_ID>`` owned by the services' user; the run directory removed after."""
    doc = yaml.safe_load(compose_file.read_text())
    mount = doc["services"]["netem"]["volumes"][0].split(":")[0]
    scenario_file = (ROOT / mount).resolve()
    (uid, gid), owner = _run_as()
    suffix = ("-late" if "late" in request.node.name else "") + (
        {PLUGINS: "-plugins", ROBOTS: "-robots"}.get(compose_file, "")
    )
    run_id = f"{engine.name}{suffix}-{os.getpid()}"
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
    scenario = Scenario.from_file(scenario_file)
    dep = Deployment(engine, compose_file, doc, scenario_file, scenario, run_id, env, owner)
    _compose(dep, "down", timeout_s=DOWN_S)  # leftovers of an interrupted run
    try:
        yield dep
    finally:
        shutil.rmtree(run_dir, ignore_errors=True)
        if made_runs and not any(runs.iterdir()):
            runs.rmdir()


def _compose(dep: Deployment, *args: str, timeout_s: float) -> subprocess.CompletedProcess[str]:
    argv = [*dep.engine.compose, *dep.files, *args]
    return subprocess.run(
        argv, cwd=ROOT, env=dep.env, capture_output=True, text=True, timeout=timeout_s, check=False
    )


def _containers(dep: Deployment) -> dict[str, str]:
    """Container name → status line, of the compose project."""
    out = subprocess.run(
        [dep.engine.cli, "ps", "-a", "--filter", f"label={dep.engine.project_label}={dep.project}",
         "--format", "{{.Names}}\t{{.Status}}"],
        capture_output=True, text=True, check=True, timeout=60,
    ).stdout  # fmt: skip
    return dict(line.split("\t", 1) for line in out.splitlines() if "\t" in line)


def _failed(dep: Deployment) -> None:
    """Raise, with its log, when a service of the project has exited with an error."""
    failed = {
        n: s for n, s in _containers(dep).items() if s.startswith("Exited") and "(0)" not in s
    }
    if failed:
        name = next(iter(failed))
        logs = subprocess.run([dep.engine.cli, "logs", name], capture_output=True, text=True)
        raise AssertionError(f"{failed}; {name}'s log:\n{(logs.stdout + logs.stderr)[-3000:]}")


def _wait_netem(dep: Deployment, timeout_s: float) -> int:
    """netem's exit code; fails early, with its log, when another service fails.

    Under Docker through ``docker compose wait netem``, started while netem runs, as the README
    has it (it finds no container once netem has exited); podman-compose has no ``wait``.
    """
    netem = dep.engine.container(dep.project, "netem")
    argv = [*dep.engine.compose, *dep.files, "wait", "netem"]
    wait = None
    if dep.engine.cli == "docker":
        wait = subprocess.Popen(
            argv, cwd=ROOT, env=dep.env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
        )
    try:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            _failed(dep)
            if wait is not None and wait.poll() is not None:
                said = wait.communicate()[0]
                assert "exited with status code" in said, said[-3000:]  # not compose's own error
                return wait.returncode
            if wait is None and _containers(dep).get(netem, "").startswith("Exited"):
                code = subprocess.run(
                    ["podman", "wait", netem], capture_output=True, text=True, check=True,
                    timeout=60,
                )  # fmt: skip
                return int(code.stdout.strip())
            time.sleep(0.2)
        raise AssertionError(f"netem did not exit within {timeout_s} s: {_containers(dep)}")
    finally:
        if wait is not None and wait.poll() is None:
            wait.kill()
            wait.wait()


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


def _up(dep: Deployment, *services: str) -> subprocess.CompletedProcess[str]:
    """``up -d``: under Docker with ``--build``, as the README says (every layer is cached)."""
    build = ["--build"] if dep.engine.cli == "docker" and not services else []
    return _compose(dep, "up", *build, "-d", *services, timeout_s=300)


@pytest.mark.parametrize(
    "compose_file", [COMPOSE, PLUGINS], ids=["paper", "plugins"], indirect=True
)
def test_compose_yaml_equals_a_native_run(deployment: Deployment, tmp_path: Path) -> None:
    """compose.yaml, and compose.plugins.yaml: the example plug-ins installed in the image."""
    dep = deployment
    t0 = time.monotonic()
    try:
        up = _up(dep)
        assert up.returncode == 0, up.stdout[-2000:] + up.stderr[-3000:]
        t_up = time.monotonic()
        assert _wait_netem(dep, WAIT_S) == 0
        t_exit = time.monotonic()
    finally:
        down = _compose(dep, "down", timeout_s=DOWN_S)
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
    assert ours.scenario.strategy.name == dep.scenario.strategy.name  # the plug-in's, if any
    print(
        f"\n{dep.engine.name}: up {t_up - t0:.1f} s, netem's exit after {t_exit - t_up:.1f} s, "
        f"down {t_down - t_exit:.1f} s: {containers:.1f} s in all; native formation run "
        f"{native_s:.1f} s; final formation error {ours.formation_error[-1]:.6g} m (both); "
        f"files owned by uid {dep.owner}"
    )


@pytest.mark.parametrize("compose_file", [ROBOTS], ids=["robots"], indirect=True)
def test_the_ros2_profile_runs_the_plant_and_equals_the_simulator(deployment: Deployment) -> None:
    """compose.ros2.yaml with ``--profile ros2``: five agents whose bodies are ROS 2 robots of
    the headless plant, over DDS between containers; lockstep, so the run equals
    ``formation simulate`` to the bit, and each robot's traffic is recorded in ROS 2's encoding."""
    dep = deployment
    try:
        up = _up(dep)
        assert up.returncode == 0, up.stdout[-2000:] + up.stderr[-3000:]
        assert _containers(dep).get(dep.engine.container(dep.project, "plant"), "").startswith("Up")
        assert _wait_netem(dep, WAIT_S) == 0
    finally:
        down = _compose(dep, "down", timeout_s=DOWN_S)
    assert down.returncode == 0, down.stderr[-3000:]
    got = _check_run(dep)
    body = {t: s for t, s in got["schemas"].items() if "/body/" in t}
    assert {t.split("/")[3] for t in body} == {str(i) for i in range(1, dep.scenario.n + 1)}
    assert {s[1] for s in body.values()} == {"ros2msg"}
    run = read_run(dep.run_dir / "run.mcap")
    np.testing.assert_array_equal(run.positions, simulate(dep.scenario).positions)


def test_router_started_late_still_gives_a_complete_run(deployment: Deployment) -> None:
    """Every service but the router up first; the router 10 s later: the clients retry."""
    dep = deployment
    clients = [n for n in dep.doc["services"] if n != "router"]
    try:
        up = _up(dep, "--no-deps", *clients)
        assert up.returncode == 0, up.stdout[-2000:] + up.stderr[-3000:]
        t_up = time.monotonic()
        while time.monotonic() - t_up < LATE_S:  # the delay is the test; no one may give up
            _failed(dep)
            time.sleep(0.5)
        states = _containers(dep)
        names = {n: dep.engine.container(dep.project, n) for n in clients}
        assert sorted(states) == sorted(names.values()), states
        assert all(s.startswith("Up") for s in states.values()), states
        router = _compose(dep, "up", "-d", "--no-deps", "router", timeout_s=120)
        assert router.returncode == 0, router.stdout[-2000:] + router.stderr[-3000:]
        assert _wait_netem(dep, WAIT_S) == 0
        # the clients waited for the router; `restart: on-failure` did not start them again
        restarts = subprocess.run(
            [dep.engine.cli, "inspect", "--format", "{{.Name}} {{.RestartCount}}",
             *names.values()],
            capture_output=True, text=True, check=True, timeout=60,
        ).stdout  # fmt: skip
        # Docker's names start with "/"
        got = dict(line.lstrip("/").split() for line in restarts.splitlines())
        assert got == {name: "0" for name in names.values()}
    finally:
        down = _compose(dep, "down", timeout_s=DOWN_S)
    assert down.returncode == 0, down.stderr[-3000:]
    _check_run(dep)
