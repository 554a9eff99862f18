"""Nothing bypasses netem: every Zenoh session of the product has multicast scouting and shared
memory off, so two processes on one host never find each other or talk past the router (and
netem's dropping proxy behind it). Local runs, compose and ROS 2 bodies over rmw_zenoh (the
agent's own session) all open theirs through ``shell.session_config``."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
import zenoh

from formation.scenario import Scenario
from shell import session_config
from testbed.deploy import security
from testbed.deploy.compose import PLANT, ROUTER, ComposeOptions, document

ROOT = Path(__file__).resolve().parents[3]
PRODUCT = (
    "formation",
    "shell",
    "body",
    "analysis",
    "agent",
    "leader",
    "netem",
    "recorder",
    "testbed",
)
# the only places a zenoh.Config is made: each turns both off, whatever the user's file says
CONFIG_MAKERS = {"shell/zenoh_config.py", "testbed/deploy/security.py"}
# every one opens its session through shell.serve (the recording service runs the recorder's)
SERVICES = {
    "agent",
    "leader",
    "netem",
    "testbed.runtime.recording_service",
    "testbed.runtime.router",
}
BOTH_ON = "{scouting: {multicast: {enabled: true}}, transport: {shared_memory: {enabled: true}}}"


def _off(conf: zenoh.Config) -> bool:
    return (
        conf.get_json("scouting/multicast/enabled") == "false"
        and conf.get_json("transport/shared_memory/enabled") == "false"
    )


def test_zenohs_defaults_would_let_processes_meet_past_the_router() -> None:
    conf = zenoh.Config()
    assert conf.get_json("scouting/multicast/enabled") != "false"  # null: the mode's, on
    assert conf.get_json("transport/shared_memory/enabled") == "true"


@pytest.mark.parametrize("mode", ["router", "client", "peer"])
def test_every_session_config_has_both_off_even_under_a_file_that_turns_them_on(
    mode: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    user = tmp_path / "zenoh.json5"
    user.write_text(BOTH_ON)
    monkeypatch.setenv("ZENOH_CONFIG", str(user))
    assert _off(session_config(mode))
    assert _off(security.client_session_config("tcp/127.0.0.1:7447", user))


def test_no_module_of_the_product_makes_a_zenoh_config_of_its_own() -> None:
    makers = set()
    for package in PRODUCT:
        for path in (ROOT / package).rglob("*.py"):
            text = path.read_text()
            if "Config" not in text and "from_file" not in text:
                continue
            for node in ast.walk(ast.parse(text)):
                call = node.func if isinstance(node, ast.Call) else None
                if isinstance(call, ast.Attribute) and call.attr in ("Config", "from_file"):
                    base = call.value
                    named = base.id if isinstance(base, ast.Name) else getattr(base, "attr", "")
                    if named in ("zenoh", "Config"):
                        makers.add(str(path.relative_to(ROOT)))
    assert makers == CONFIG_MAKERS


@pytest.mark.parametrize("options", [ComposeOptions(), ComposeOptions(secure=False)])
@pytest.mark.parametrize("name", ["paper.toml", "robots.toml"])
def test_every_compose_service_opens_its_session_with_both_off(
    name: str,
    options: ComposeOptions,
    paper_path: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    path = paper_path.parent / name  # beside the default scenario
    scenario = Scenario.from_file(path)
    keys = security.generate(tmp_path / "keys", scenario.n, body=scenario.body)
    services = document(scenario, path, options)["services"]
    for service, spec in services.items():
        command = spec["command"]
        if service == PLANT:  # ROS 2 over DDS: no Zenoh session at all
            assert (
                command[:2] == ["formation", "ros2-plant"]
                and "ZENOH_MODE" not in spec["environment"]
            )
            continue
        assert command[:2] == ["python", "-m"] and command[2] in SERVICES, (service, command)
        with monkeypatch.context() as env:
            for key, value in spec["environment"].items():
                env.setenv(key, str(value))
            if "ZENOH_CONFIG" in spec["environment"]:  # the service's secret, as mounted
                secret = keys.router_config if service == ROUTER else keys.config(service)
                env.setenv("ZENOH_CONFIG", str(secret))
            mode = "router" if service == ROUTER else None  # the router's own flag
            assert _off(session_config(mode)), service
