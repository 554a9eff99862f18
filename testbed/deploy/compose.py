"""``formation compose SCENARIO > compose.yaml``: the deployment of a scenario as Compose services.

One image (the repository's ``Dockerfile``), one service per process of a run:
``router`` (``python -m testbed.runtime.router``), ``recorder``, ``netem``, ``leader``
and ``agent-<i>`` for every agent of the scenario. Every service reaches the
others only through the router, in ``client`` mode, by the service name
``router``; nothing names a host address. The scenario file is a read-only bind
mount, the run directory a volume, the run id comes from ``RUN_ID`` (default:
the scenario's name).

Portable between Docker Compose and podman-compose: only the ``router`` service
builds the image, the others use it by name (``image:``); no ``configs:``
(podman-compose ignores them) and no health conditions (podman-compose ignores
them too): a client retries until the router answers
(:func:`shell.zenoh_config.open_with_retry`), ``depends_on`` keeps the start
order only. Every service runs as ``${FORMATION_UID:-1000}:${FORMATION_GID:-1000}``,
the invoking user's ids when those are exported, so what it writes in ``./runs``
is theirs and it can read its 0600 secret.

Closed by default: each service gets its own Zenoh config as a Compose secret
(``formation keys keys/`` writes them; see :mod:`testbed.deploy.security`), the router
checks passwords and enforces access control. ``--open`` leaves both out (a
trusted network only); ``--tls`` puts the links on TLS (``formation keys --tls``).

The recorder's container runs :mod:`testbed.runtime.recording_service`: on
``docker compose down`` it finishes ``run.mcap`` and writes ``report.md``.

A scenario whose agents have ROS 2 bodies (``[body] kind = "ros2"``, docs/robots.md) gets an
image with the extra ``ros2`` (build argument ``EXTRAS``), DDS discovery on the Compose network
(``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET``) in its domain for those agents, and the headless
plant as the service ``plant`` of the optional profile ``ros2``: ``docker compose --profile
ros2 up`` runs it in place of the robots (its clock by the scenario's mode). It is no Zenoh
member: it speaks DDS only.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any

import yaml

from formation.body import EXTRA
from formation.errors import TestbedError
from formation.scenario import Scenario
from shell import MEMBER_ENV, MEMBERS_ENV
from testbed.deploy import security
from testbed.runtime.processes import SERVICE_ENV

ROUTER = "router"
PLANT = "plant"  # the headless ROS 2 plant (profile ros2)
PORT = 7447
APP = PurePosixPath("/app")
RUNS = APP / "runs"
SCENARIO = APP / "scenario.toml"
SECRETS = PurePosixPath("/run/secrets")
ZENOH_CONFIG = "zenoh.json5"  # each service's secret, mounted as /run/secrets/zenoh.json5
PASSWORDS = security.PASSWORDS_FILE
IMAGE = "${FORMATION_IMAGE:-formation-testbed:latest}"
KEYS_DIR = "${FORMATION_KEYS:-./keys}"
RUNS_DIR = "${FORMATION_RUNS:-./runs}"
STOP_GRACE = "2m"  # the recorder finishes the MCAP file and writes the report [s]
# A crashed agent or leader comes back and rejoins the run (issue 20); netem's exit ends it.
RESTART = {"restart": "on-failure"}
USER = "${FORMATION_UID:-1000}:${FORMATION_GID:-1000}"  # the invoking user (export them)


@dataclass(frozen=True)
class ComposeOptions:
    """How the deployment is secured and where its image comes from."""

    secure: bool = True  # usrpwd authentication and access control (formation keys)
    tls: bool = False  # tls/ endpoints; needs `formation keys --tls`
    image: str = IMAGE
    # plug-in packages the image installs (the Dockerfile's PLUGINS: pip requirements, or
    # folders of the build context such as ./examples/formation-plugins-example)
    plugins: tuple[str, ...] = ()
    file: str = "compose.yaml"  # where the file is written (named by its usage lines)

    @property
    def endpoint(self) -> str:
        return f"{'tls' if self.tls else 'tcp'}/{ROUTER}:{PORT}"

    def __post_init__(self) -> None:
        if self.tls and not self.secure:
            raise TestbedError("--tls needs the keys (the router's certificate); not with --open")


def upstream_router(options: ComposeOptions) -> str:
    """A comment: the upstream Zenoh router image as the ``router`` service instead of ours."""
    args = ["-l", options.endpoint, "--no-multicast-scouting"]
    if options.secure:
        dictionary = f'transport/auth/usrpwd/dictionary_file:"{SECRETS / PASSWORDS}"'
        args = ["-c", str(SECRETS / ZENOH_CONFIG), *args, "--cfg", dictionary]
    head, tail = (args[:5], args[5:]) if options.secure else (args, [])  # two lines if long
    lines = [
        "The upstream Zenoh router image may replace ours as the router service (match its",
        "version to eclipse-zenoh in pyproject.toml)"
        + (", with the same secrets:" if options.secure else ":"),
        "  router:",
        "    image: eclipse/zenoh:1.10.2",
        f"    command: {json.dumps(head)}",
    ]
    if tail:
        lines[-1] = lines[-1].removesuffix("]") + ","
        lines.append(f"              {json.dumps(tail).removeprefix('[')}")
    return "".join(f"# {line}\n" for line in lines)


def compose_path(scenario_path: str | Path) -> str:
    """The scenario file as the compose file names it: ``./`` + the path for a relative one."""
    p = Path(scenario_path)
    return p.as_posix() if p.is_absolute() else f"./{p.as_posix()}"


def document(
    scenario: Scenario, scenario_path: str | Path, options: ComposeOptions
) -> dict[str, Any]:
    """The compose file as a mapping, services in start order."""
    mount = (
        f"{compose_path(scenario_path)}:{SCENARIO}:ro"  # not configs: podman-compose ignores them
    )
    run_id = f"${{RUN_ID:-{scenario.name}}}"
    scenario_args = ["--scenario", str(SCENARIO), "--run-id", run_id]
    services: dict[str, dict[str, Any]] = {
        ROUTER: _router(options),
        "recorder": _service(
            options,
            "recorder",
            [
                "python",
                "-m",
                "testbed.runtime.recording_service",
                "--report",
                "--host-out",
                f"{RUNS_DIR}/{run_id}",
                "--run-id",
                run_id,
                "--out",
                f"{RUNS}/{run_id}",
                "--scenario",
                str(SCENARIO),
            ],
            volumes=[mount, f"{RUNS_DIR}:{RUNS}"],
            extra={"stop_grace_period": STOP_GRACE},
        ),
        "netem": _service(
            options,
            "netem",
            ["python", "-m", "netem", *scenario_args],
            volumes=[mount],
            after=["recorder"],
        ),
        "leader": _service(
            options,
            "leader",
            ["python", "-m", "leader", *scenario_args],
            volumes=[mount],
            extra=RESTART,
        ),
    }
    for i in range(1, scenario.n + 1):
        name = security.agent_user(i)
        services[name] = _service(
            options,
            name,
            ["python", "-m", "agent", *scenario_args, "--id", str(i)],
            volumes=[mount],
            extra=RESTART,
        )
    for name, service in services.items():  # the team (shell/zenoh_config.py): only it blocks
        service["environment"].update({MEMBER_ENV: name, MEMBERS_ENV: ",".join(services)})
    robots = scenario.body.robots(scenario.n) if scenario.body.kind == "ros2" else []
    if robots:
        dds = _dds(scenario)
        for i in robots:
            services[security.agent_user(i)]["environment"].update(dds)
        services[ROUTER]["build"]["args"] = {"EXTRAS": f"[{EXTRA}]"}
        clock = "free" if scenario.runtime.mode == "realtime" else "stepped"
        services[PLANT] = {
            **_common(options),
            "profiles": [EXTRA],  # --profile ros2: the headless plant instead of the robots
            "command": ["formation", "ros2-plant", str(SCENARIO), "--clock", clock],
            "environment": dds,
            "volumes": [mount],
            "init": True,
        }
    doc: dict[str, Any] = {"name": "formation", "services": services}
    if options.secure:
        users = [ROUTER, *(name for name in services if name not in (ROUTER, PLANT))]
        doc["secrets"] = {
            u: {"file": f"{KEYS_DIR}/{security.ROUTER_CONFIG if u == ROUTER else u + '.json5'}"}
            for u in users
        }
        doc["secrets"][PASSWORDS.removesuffix(".txt")] = {"file": f"{KEYS_DIR}/{PASSWORDS}"}
    return doc


def _dds(scenario: Scenario) -> dict[str, str]:
    """Fast DDS between the containers of the ROS 2 bodies and the plant: the Compose network."""
    domain = scenario.body.domain_id
    return {
        "ROS_DOMAIN_ID": str(0 if domain is None else domain),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET",
        "ROS_LOG_DIR": "/tmp/ros-log",  # rclpy writes its logs there; HOME may not be writable
    }


def _common(options: ComposeOptions, build: bool = False) -> dict[str, Any]:
    """The image; only the router's service builds it (``up --build`` builds it once)."""
    args = {"args": {"PLUGINS": " ".join(options.plugins)}} if options.plugins else {}
    built = {"build": {"context": ".", "dockerfile": "Dockerfile", **args}} if build else {}
    return {"image": options.image, **built, "user": USER}


def _secrets(options: ComposeOptions, user: str) -> dict[str, Any]:
    if not options.secure:
        return {}
    return {"secrets": [{"source": user, "target": ZENOH_CONFIG}]}


def _zenoh_config(options: ComposeOptions) -> dict[str, str]:
    return {"ZENOH_CONFIG": str(SECRETS / ZENOH_CONFIG)} if options.secure else {}


def _router(options: ComposeOptions) -> dict[str, Any]:
    command = ["python", "-m", "testbed.runtime.router"]
    secrets_: dict[str, Any] = {}
    if options.secure:
        command += ["--passwords", str(SECRETS / PASSWORDS)]
        secrets_ = {
            "secrets": [
                {"source": ROUTER, "target": ZENOH_CONFIG},
                {"source": PASSWORDS.removesuffix(".txt"), "target": PASSWORDS},
            ]
        }
    return {
        **_common(options, build=True),
        "command": command,
        "environment": {"ZENOH_LISTEN": options.endpoint, **_zenoh_config(options)},
        **secrets_,
        "init": True,
    }


def _service(
    options: ComposeOptions,
    user: str,
    command: list[str],
    volumes: list[str],
    after: list[str] | None = None,
    extra: dict[str, Any] | None = None,
) -> dict[str, Any]:
    depends = [
        ROUTER,
        *(after or []),
    ]  # start order only: a client retries until the router answers
    return {
        **_common(options),
        "command": command,
        "environment": {
            "ZENOH_MODE": "client",
            "ZENOH_CONNECT": options.endpoint,
            **_zenoh_config(options),
            **SERVICE_ENV,
        },
        **_secrets(options, user),
        "volumes": volumes,
        **(extra or {}),
        "depends_on": depends,
        "init": True,
    }


def _increase_indent(self: Any, flow: bool = False, indentless: bool = False) -> None:
    yaml.SafeDumper.increase_indent(self, flow, False)  # sequences indented under their key


def _represent_list(dumper: Any, data: list[Any]) -> Any:
    flow = all(isinstance(x, (str, int, float, bool)) for x in data)  # commands on one line
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


_Dumper: Any = type("_Dumper", (yaml.SafeDumper,), {"increase_indent": _increase_indent})
_Dumper.add_representer(list, _represent_list)


def render(
    scenario_path: str | Path,
    options: ComposeOptions | None = None,
    scenario: Scenario | None = None,
) -> str:
    """The compose file's text for ``scenario_path`` (what ``formation compose`` prints)."""
    options = options or ComposeOptions()
    scenario = scenario or Scenario.from_file(scenario_path)
    flags = ("" if options.secure else " --open") + (" --tls" if options.tls else "")
    flags += "".join(f" --plugin {p}" for p in options.plugins)
    if options.file != "compose.yaml":
        flags += f" --file {options.file}"
    file = "" if options.file == "compose.yaml" else f" -f {options.file}"
    plant = scenario.body.kind == "ros2" and bool(scenario.body.robots(scenario.n))
    if plant:  # the headless plant in place of robots; left out, real robots answer
        file += f" --profile {EXTRA}"
    keys_cmd = f"formation keys keys/ {Path(scenario_path).as_posix()}" + (
        " --tls" if options.tls else ""
    )
    usage = [
        f"# Generated by `formation compose {Path(scenario_path).as_posix()}{flags}"
        + ("`" if not file else f" > {options.file}`")
        + "; do not edit.",
        f"# Scenario {scenario.name!r}: {scenario.n} agents, {scenario.epochs} epochs.",
        "#",
    ]
    if options.secure:
        usage.append(f"#   {keys_cmd}    # credentials and access control, once (not in git)")
    usage += [
        "#   mkdir -p runs; export FORMATION_UID=$(id -u) FORMATION_GID=$(id -g)",
        f"#   docker compose{file} up --build -d",
        f"#   docker compose{file} wait netem       # the run is over when netem exits",
        f"#   docker compose{file} down             # the recorder finishes run.mcap and report.md",
        "# Files: ./runs/$RUN_ID/ (RUN_ID defaults to the scenario's name). podman-compose runs it",
        "# too (README, Deployment; no `wait`: `podman wait formation_netem_1`).",
        *(
            [
                f"# --profile {EXTRA} runs the headless plant `{PLANT}`; leave it out with real robots."
            ]
            if plant
            else []
        ),
        "#",
    ]
    body: str = yaml.dump(
        document(scenario, scenario_path, options),
        Dumper=_Dumper,
        sort_keys=False,
        width=100,
        default_flow_style=False,
    )
    return "\n".join(usage) + "\n" + upstream_router(options) + body


__all__ = ["ComposeOptions", "compose_path", "document", "render"]
