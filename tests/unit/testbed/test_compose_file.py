"""compose.yaml: generated, valid Compose, closed by default; the keys and the access control behind it."""

from __future__ import annotations

import json
import stat
from pathlib import Path

import jsonschema
import pytest
import yaml
import zenoh

from formation import keys
from formation.errors import KeysError, TestbedError
from formation.scenario import Scenario
from testbed.cli import main as formation
from testbed.deploy import security
from testbed.deploy.compose import ComposeOptions, render
from testkit.loopback import LoopbackDeployment, interpolate, parse_duration_s

ROOT = Path(__file__).resolve().parents[3]
COMPOSE = ROOT / "compose.yaml"
SCHEMA = ROOT / "tests" / "data" / "compose-spec.json"  # Apache-2.0, see tests/data/README.md
DEFAULT = "scenarios/paper.toml"
OPTIONS = [ComposeOptions(), ComposeOptions(secure=False), ComposeOptions(tls=True)]


def _render(path: str, options: ComposeOptions | None = None) -> str:
    return render(path, options, Scenario.from_file(ROOT / path))


@pytest.fixture(scope="module")
def compose_schema() -> jsonschema.Draft7Validator:
    """The Compose Specification's schema; it declares draft-07 by a URL jsonschema does not know."""
    schema = json.loads(SCHEMA.read_text())
    assert schema["$schema"].startswith("https://json-schema.org/draft-07/")
    jsonschema.Draft7Validator.check_schema(schema)
    return jsonschema.Draft7Validator(schema)


def test_committed_compose_file_is_what_the_generator_writes_now() -> None:
    assert COMPOSE.read_text() == _render(DEFAULT), "regenerate: formation compose > compose.yaml"


def test_the_plugins_compose_file_is_generated_and_builds_the_example_into_the_image(
    compose_schema: jsonschema.Draft7Validator,
) -> None:
    example = "examples/formation-plugins-example"
    options = ComposeOptions(plugins=(f"./{example}",), file="compose.plugins.yaml")
    text = _render(f"{example}/scenario.toml", options)
    assert (ROOT / "compose.plugins.yaml").read_text() == text, (
        f"regenerate: formation compose {example}/scenario.toml --plugin ./{example} "
        "--file compose.plugins.yaml > compose.plugins.yaml"
    )
    doc = yaml.safe_load(text)
    assert doc["services"]["router"]["build"]["args"] == {"PLUGINS": f"./{example}"}
    assert (ROOT / example / "pyproject.toml").is_file()  # inside the build context
    compose_schema.validate(doc)
    assert "docker compose -f compose.plugins.yaml up --build -d" in text


def test_the_robots_compose_file_is_generated_with_the_plant_in_its_profile(
    compose_schema: jsonschema.Draft7Validator,
) -> None:
    options = ComposeOptions(file="compose.ros2.yaml")
    text = _render("scenarios/robots.toml", options)
    assert (ROOT / "compose.ros2.yaml").read_text() == text, (
        "regenerate: formation compose scenarios/robots.toml --file compose.ros2.yaml "
        "> compose.ros2.yaml"
    )
    doc = yaml.safe_load(text)
    compose_schema.validate(doc)
    assert doc["services"]["plant"]["profiles"] == ["ros2"]
    assert "docker compose -f compose.ros2.yaml --profile ros2 up --build -d" in text


def test_agents_and_the_leader_restart_on_failure_and_nothing_else_does() -> None:
    """A crashed agent or leader rejoins the run (issue 20); netem, router and recorder do not
    restart: netem's exit is the run's end, and a recorder restarted would start a new file."""
    doc = yaml.safe_load(COMPOSE.read_text())
    restarts = {name for name, svc in doc["services"].items() if svc.get("restart") == "on-failure"}
    assert restarts == {"leader", *(s for s in doc["services"] if s.startswith("agent-"))}
    assert not any("restart" in doc["services"][s] for s in ("router", "recorder", "netem"))


def test_formation_compose_prints_the_file(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(ROOT)
    assert formation(["compose"]) == 0
    assert capsys.readouterr().out == COMPOSE.read_text()


@pytest.mark.parametrize("scenario", sorted(p.name for p in (ROOT / "scenarios").glob("*.toml")))
@pytest.mark.parametrize("options", OPTIONS, ids=["closed", "open", "tls"])
def test_every_scenario_gives_a_valid_compose_file(
    scenario: str, options: ComposeOptions, compose_schema: jsonschema.Draft7Validator
) -> None:
    text = _render(f"scenarios/{scenario}", options)
    doc = yaml.safe_load(text)
    compose_schema.validate(doc)
    n = Scenario.from_file(ROOT / "scenarios" / scenario).n
    agents = [s for s in doc["services"] if s.startswith("agent-")]
    assert agents == [f"agent-{i}" for i in range(1, n + 1)]
    assert list(doc["services"])[:4] == ["router", "recorder", "netem", "leader"]
    assert "configs" not in doc  # podman-compose ignores them: the scenario is a bind mount
    mount = f"./scenarios/{scenario}:/app/scenario.toml:ro"
    builders = [name for name, svc in doc["services"].items() if "build" in svc]
    assert builders == ["router"]  # one service builds the image, the others use it
    assert {svc["image"] for svc in doc["services"].values()} == {
        "${FORMATION_IMAGE:-formation-testbed:latest}"
    }
    for banned in ("localhost", "127.", "0.0.0.0", "::"):  # names only; compose resolves them
        assert banned not in yaml.safe_dump(doc["services"])
    proto = "tls" if options.tls else "tcp"
    for name, svc in doc["services"].items():
        env = svc["environment"]
        if name == "router":
            assert env["ZENOH_LISTEN"] == f"{proto}/router:7447"
            continue
        if name == "plant":  # the robots' stand-in speaks DDS only (scenarios/robots.toml)
            assert not any(k.startswith("ZENOH") for k in env) and svc["volumes"][0] == mount
            continue
        assert env["ZENOH_MODE"] == "client" and env["ZENOH_CONNECT"] == f"{proto}/router:7447"
        assert svc["depends_on"][0] == "router"  # start order only; clients retry
        assert "healthcheck" not in svc and "condition" not in str(svc["depends_on"])
        assert "--scenario" in svc["command"] and "/app/scenario.toml" in svc["command"]
        assert svc["volumes"][0] == mount
        assert svc["user"] == "${FORMATION_UID:-1000}:${FORMATION_GID:-1000}"
        assert "${RUN_ID:-" in " ".join(svc["command"])


def test_committed_compose_file_validates_against_the_compose_spec(
    compose_schema: jsonschema.Draft7Validator,
) -> None:
    doc = yaml.safe_load(COMPOSE.read_text())
    compose_schema.validate(doc)
    doc["services"]["netem"]["restart_policy"] = "always"  # a typo of `restart`: the check is live
    with pytest.raises(
        jsonschema.ValidationError, match="'restart_policy' does not match any of the regexes"
    ):
        compose_schema.validate(doc)


def test_closed_by_default_each_service_has_its_own_credentials() -> None:
    doc = yaml.safe_load(COMPOSE.read_text())
    n = Scenario.from_file(ROOT / DEFAULT).n
    users = {p.user for p in security.principals(n)} - {security.OPERATOR}
    assert set(doc["services"]) - {"router"} == users
    for name, svc in doc["services"].items():
        assert svc["environment"]["ZENOH_CONFIG"] == "/run/secrets/zenoh.json5"
        assert {"source": name, "target": "zenoh.json5"} in svc["secrets"]
        assert doc["secrets"][name]["file"].startswith("${FORMATION_KEYS:-./keys}/")
    assert "--passwords" in doc["services"]["router"]["command"]
    recorder = doc["services"]["recorder"]
    assert "--report" in recorder["command"] and recorder["volumes"] == [
        "./scenarios/paper.toml:/app/scenario.toml:ro",
        "${FORMATION_RUNS:-./runs}:/app/runs",
    ]
    host_out = recorder["command"][recorder["command"].index("--host-out") + 1]
    assert host_out == "${FORMATION_RUNS:-./runs}/${RUN_ID:-paper}"  # the report names host paths
    assert recorder["stop_grace_period"] == "2m"
    assert (ROOT / "Dockerfile").is_file() and "keys" in (
        ROOT / ".dockerignore"
    ).read_text().split()
    open_doc = yaml.safe_load(_render(DEFAULT, ComposeOptions(secure=False)))
    assert "secrets" not in open_doc and all(
        "secrets" not in s for s in open_doc["services"].values()
    )


@pytest.mark.parametrize("options", OPTIONS[:2], ids=["closed", "open"])
def test_the_upstream_router_alternative_is_a_valid_service_once_uncommented(
    options: ComposeOptions, compose_schema: jsonschema.Draft7Validator
) -> None:
    text = _render(DEFAULT, options)
    block = [line[2:] for line in text.splitlines() if line.startswith("#   ")]
    alternative = yaml.safe_load(
        "\n".join(
            line for line in block if not line.lstrip().startswith(("formation", "docker", "mkdir"))
        )
    )
    doc = yaml.safe_load(text)
    doc["services"]["router"] = {
        **alternative["router"],
        "secrets": doc["services"]["router"].get("secrets", []),
    }
    compose_schema.validate(doc)
    command = alternative["router"]["command"]
    assert command[command.index("-l") + 1] == "tcp/router:7447"
    assert ("-c" in command) is options.secure


def test_tls_needs_the_keys() -> None:
    with pytest.raises(
        TestbedError, match=r"--tls needs the keys \(the router's certificate\); not with --open"
    ):
        ComposeOptions(secure=False, tls=True)


# -- the access control --------------------------------------------------------------------------
def _allows(acl: dict, user: str, message: str, flow: str, key: str) -> bool:
    """Whether ``acl`` lets ``user`` send ``message`` on ``key`` (explicit allow; default deny)."""
    policy = next(p for p in acl["policies"] if p["subjects"] == [user])
    rules = [r for r in acl["rules"] if r["id"] in policy["rules"]]
    return any(
        message in r["messages"] and flow in r["flows"]
        and any(zenoh.KeyExpr(e).includes(zenoh.KeyExpr(key)) for e in r["key_exprs"])
        for r in rules
    )  # fmt: skip


@pytest.mark.parametrize(
    ("user", "key", "allowed"),
    [
        ("agent-1", keys.agent_state("r", 1), True),
        ("agent-1", keys.agent_report("r", 1), True),
        ("agent-1", keys.status("r", "agent", 1), True),
        ("agent-1", keys.agent_state("r", 2), False),
        ("agent-1", keys.link_state("r", 1, 2), False),
        ("agent-1", keys.leader_estimate_out("r"), False),
        ("agent-2", keys.agent_state("r", 2), True),
        ("agent-2", keys.body("r", 2, "pose", "geometry_msgs/msg/PoseStamped"), True),
        ("agent-2", keys.body("r", 2, "command", "geometry_msgs/msg/Twist"), True),
        ("agent-2", keys.body("r", 3, "command", "geometry_msgs/msg/Twist"), False),
        ("netem", keys.link_state("r", 1, 2), True),
        ("netem", keys.link_report("r", 3), False),  # realtime delivers on inbox keys too
        ("netem", keys.link_estimate("r", 3), False),
        ("netem", keys.inbox("r", 0, "report"), True),
        ("netem", keys.netem_decision("r"), True),
        ("netem", keys.agent_state("r", 1), False),
        ("netem", keys.leader_estimate_out("r"), False),
        ("leader", keys.leader_estimate_out("r"), True),
        ("leader", keys.link_estimate("r", 1), False),
        ("recorder", keys.status("r", "recorder", 0), True),
        ("recorder", keys.agent_state("r", 1), False),
        ("operator", keys.agent_state("r", 1), False),
    ],
)
def test_each_user_may_publish_only_its_own_keys(user: str, key: str, allowed: bool) -> None:
    acl = security.access_control(security.principals(5))
    assert acl["default_permission"] == "deny"
    assert _allows(acl, user, "put", "ingress", key) is allowed
    assert _allows(acl, user, "declare_subscriber", "ingress", keys.everything("r"))
    assert _allows(acl, user, "put", "egress", key)  # everyone authenticated may read the run


def test_liveliness_tokens_and_queryables_belong_to_their_owner() -> None:
    acl = security.access_control(security.principals(3))
    assert _allows(acl, "agent-3", "liveliness_token", "ingress", keys.alive("r", "agent", 3))
    assert not _allows(acl, "agent-3", "liveliness_token", "ingress", keys.alive("r", "agent", 2))
    assert not _allows(acl, "agent-3", "liveliness_token", "ingress", keys.start("r"))
    assert _allows(acl, "netem", "liveliness_token", "ingress", keys.start("r"))
    assert _allows(acl, "netem", "declare_queryable", "ingress", keys.netem_config("r"))
    assert not _allows(acl, "agent-1", "declare_queryable", "ingress", keys.netem_config("r"))
    assert _allows(acl, "operator", "query", "ingress", keys.flush("r"))
    assert not _allows(acl, "agent-1", "query", "ingress", keys.flush("r"))


def test_generated_keys_are_private_and_load_as_zenoh_configs(tmp_path: Path) -> None:
    keyset = security.generate(tmp_path / "k", n_agents=2)
    files = sorted(p.name for p in (tmp_path / "k").iterdir())
    assert files == sorted(["passwords.txt", "router.json5", "recorder.json5", "netem.json5", "leader.json5",
                            "agent-1.json5", "agent-2.json5", "operator.json5"])  # fmt: skip
    for p in (tmp_path / "k").iterdir():
        assert stat.S_IMODE(p.stat().st_mode) == 0o600, p
    assert len(set(keyset.passwords.values())) == len(keyset.passwords)
    lines = keyset.passwords_file.read_text().splitlines()
    assert lines == [f"{u}:{keyset.passwords[u]}" for u in keyset.configs]
    for path in [keyset.router_config, *keyset.configs.values()]:
        zenoh.Config.from_file(str(path))
    agent = json.loads(keyset.config("agent-1").read_text().split("\n", 1)[1])
    assert agent == {
        "transport": {
            "auth": {"usrpwd": {"user": "agent-1", "password": keyset.passwords["agent-1"]}}
        }
    }
    with pytest.raises(KeysError, match=r"k: exists and is not empty \(use --force to overwrite\)"):
        security.generate(tmp_path / "k", n_agents=2)


# -- the loopback translation the integration test relies on ------------------------------------
def test_interpolation_and_durations_follow_compose() -> None:
    env = {"A": "x", "EMPTY": ""}
    assert interpolate("${A:-d}/${B:-d}/${EMPTY:-d}/${EMPTY-d}/$A/$$A", env) == "x/d/d//x/$A"
    assert [parse_duration_s(t) for t in ("2m", "1m30s", "500ms", "10s", None)] == [
        120,
        90,
        0.5,
        10,
        10,
    ]
    with pytest.raises(Exception, match="cannot read duration '2 min'"):
        parse_duration_s("2 min")


def test_loopback_maps_names_paths_and_secrets(tmp_path: Path) -> None:
    env = {
        "FORMATION_KEYS": str(tmp_path / "keys"),
        "FORMATION_RUNS": str(tmp_path / "runs"),
        "RUN_ID": "r1",
    }
    dep = LoopbackDeployment(COMPOSE, tmp_path / "logs", env, subnet=(10, 20))
    assert dep.addresses["router"] == "127.10.20.2" and dep.host_address == "127.10.20.1"
    assert [s.name for s in dep.services][:3] == ["router", "recorder", "netem"]
    router = dep.service("router")
    assert router.env["ZENOH_LISTEN"] == "tcp/127.10.20.2:7447" and router.listen == [
        ("127.10.20.2", 7447)
    ]
    assert router.env["ZENOH_CONFIG"] == str(tmp_path / "keys" / "router.json5")
    assert router.argv[-1] == str(tmp_path / "keys" / "passwords.txt")
    agent = dep.service("agent-2")
    assert agent.env["ZENOH_CONNECT"] == f"tcp/127.10.20.2:7447#bind={agent.address}:0"
    assert agent.env["ZENOH_CONFIG"] == str(tmp_path / "keys" / "agent-2.json5")
    assert str((ROOT / DEFAULT).resolve()) in agent.argv and "r1" in agent.argv
    recorder = dep.service("recorder")
    assert str(tmp_path / "runs" / "r1") in recorder.argv and recorder.grace_s == 60.0
    assert dep.bound("tcp/router:7447") == "tcp/127.10.20.2:7447#bind=127.10.20.1:0"
    assert not dep.started


@pytest.mark.parametrize(
    ("compose", "loopback"),
    [
        ("compose.yaml", "compose.loopback.yaml"),
        ("compose.ros2.yaml", "compose.ros2.loopback.yaml"),
    ],
)
def test_the_loopback_override_covers_every_service_on_its_own_loopback_address(
    compose: str, loopback: str, compose_schema: jsonschema.Draft7Validator
) -> None:
    """deploy/compose*.loopback.yaml: host network, each service name → its own 127.0.0.N.

    The one service that builds builds on the host's network too: without a bridge a build
    has no network, and pip could not install the dependencies. A robot's DDS stays on this
    host, and shares its /dev/shm: Fast DDS on one host talks through it.
    """
    doc = yaml.safe_load((ROOT / compose).read_text())
    override = yaml.safe_load((ROOT / "deploy" / loopback).read_text())
    assert list(override["services"]) == list(doc["services"])
    expected = [f"{name}:127.0.0.{k + 2}" for k, name in enumerate(doc["services"])]
    for name, svc in override["services"].items():
        assert svc["network_mode"] == "host"
        assert svc["extra_hosts"] == expected, name
        ros = "ROS_DOMAIN_ID" in doc["services"][name].get("environment", {})
        assert set(svc) - {"network_mode", "extra_hosts"} == (
            {"build"} if "build" in doc["services"][name] else set()
        ) | ({"environment", "volumes"} if ros else set()), name
        merged = {**doc["services"][name], **svc}
        if "build" in svc:  # compose merges mappings key by key
            merged["build"] = {**doc["services"][name]["build"], **svc["build"]}
            assert merged["build"]["network"] == "host"
        if ros:
            merged["environment"] = {**doc["services"][name]["environment"], **svc["environment"]}
            assert merged["environment"]["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
            assert svc["volumes"] == ["/dev/shm:/dev/shm"]
            merged["volumes"] = doc["services"][name]["volumes"] + svc["volumes"]
        compose_schema.validate({**doc, "services": {name: merged}})


def test_every_service_is_of_the_team_under_its_name() -> None:
    services = yaml.safe_load(COMPOSE.read_text())["services"]
    for name, service in services.items():
        env = service["environment"]
        assert env["FORMATION_MEMBER"] == name
        assert env["FORMATION_MEMBERS"].split(",") == list(services)


@pytest.mark.parametrize("options", OPTIONS, ids=["closed", "open", "tls"])
@pytest.mark.parametrize("mode", ["lockstep", "realtime"])
def test_robots_on_ros2_get_the_extra_dds_on_the_network_and_the_plant_as_a_profile(
    options: ComposeOptions, mode: str, compose_schema: jsonschema.Draft7Validator
) -> None:
    paper = Scenario.from_file(ROOT / DEFAULT)
    robots = paper.with_overrides(
        body={"kind": "ros2", "agents": [2, 3], "domain_id": 9}, runtime={"mode": mode}
    )
    doc = yaml.safe_load(render("robots.toml", options, robots))
    compose_schema.validate(doc)
    services = doc["services"]
    assert services["router"]["build"]["args"] == {"EXTRAS": "[ros2]"}
    plant = services["plant"]
    assert plant["profiles"] == ["ros2"]  # optional: real robots, or --profile ros2
    clock = "free" if mode == "realtime" else "stepped"
    assert plant["command"] == ["formation", "ros2-plant", "/app/scenario.toml", "--clock", clock]
    dds = {
        "ROS_DOMAIN_ID": "9",
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET",
        "ROS_LOG_DIR": "/tmp/ros-log",
    }
    assert plant["environment"] == dds  # DDS only: no Zenoh, no credentials
    assert "secrets" not in plant and "plant" not in doc.get("secrets", {})
    assert "plant" not in services["agent-1"]["environment"]["FORMATION_MEMBERS"]
    for i in (1, 2, 3, 4, 5):
        env = services[f"agent-{i}"]["environment"]
        assert (env.get("ROS_DOMAIN_ID") == "9") == (i in (2, 3))
    # a scenario without robots: no plant, no extra
    plain = yaml.safe_load(render(DEFAULT, options, paper))["services"]
    assert "plant" not in plain and "args" not in plain["router"]["build"]
