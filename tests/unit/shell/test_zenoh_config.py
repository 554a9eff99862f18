"""The session opener: a client retries until its router answers, for a bounded time."""

from __future__ import annotations

import argparse
import json
from typing import Any

import pytest
import zenoh

from formation.errors import RuntimeFailure
from shell import zenoh_config


class FakeClock:
    """Time that moves only when slept through."""

    def __init__(self) -> None:
        self.now_s = 0.0
        self.pauses: list[float] = []

    def sleep(self, s: float) -> None:
        self.pauses.append(s)
        self.now_s += s

    def __call__(self) -> float:
        return self.now_s


def refusing(monkeypatch: pytest.MonkeyPatch, failures: int) -> list[int]:
    """zenoh.open fails ``failures`` times (as with nobody listening), then returns a stand-in."""
    calls = [0]

    def fake_open(conf: Any) -> Any:
        calls[0] += 1
        if calls[0] <= failures:
            raise zenoh.ZError("Unable to connect to any of [tcp/router:7447]!  at /src/x.rs:1.")
        return "session"

    monkeypatch.setattr(zenoh, "open", fake_open)
    return calls


def test_a_client_retries_until_the_router_answers(monkeypatch: pytest.MonkeyPatch) -> None:
    calls = refusing(monkeypatch, failures=5)
    clock = FakeClock()
    got = zenoh_config.open_with_retry(
        zenoh.Config(), "tcp/router:7447", 60.0, sleep=clock.sleep, clock=clock
    )
    assert got == "session"
    assert calls[0] == 6
    assert clock.pauses == [0.1, 0.2, 0.4, 0.8, 1.0]  # doubling, capped at RETRY_MAX_S


def test_no_router_within_the_bound_is_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    refusing(monkeypatch, failures=10**6)
    clock = FakeClock()
    with pytest.raises(
        RuntimeFailure,
        match=r"^cannot open a Zenoh session \(tcp/router:7447\) within 5 s \(\d+ attempts\): "
        r"Unable to connect to any of \[tcp/router:7447\]!$",
    ):
        zenoh_config.open_with_retry(
            zenoh.Config(), "tcp/router:7447", 5.0, sleep=clock.sleep, clock=clock
        )
    assert clock.now_s == pytest.approx(5.0)  # never sleeps past the bound


def test_a_peer_tries_once(monkeypatch: pytest.MonkeyPatch) -> None:
    calls = refusing(monkeypatch, failures=1)
    with pytest.raises(RuntimeFailure, match=r"^cannot open a Zenoh session \(x\): Unable"):
        zenoh_config.open_with_retry(zenoh.Config(), "x", 60.0, retry=False)
    assert calls[0] == 1


def test_only_clients_retry(monkeypatch: pytest.MonkeyPatch) -> None:
    seen: list[bool] = []
    monkeypatch.setattr(
        zenoh_config, "open_with_retry", lambda conf, where, t, retry: seen.append(retry)
    )
    monkeypatch.delenv("ZENOH_MODE", raising=False)
    for mode in ("client", "peer", "router", None):
        args = argparse.Namespace(mode=mode, connect=None, listen=None, connect_timeout=1.0)
        zenoh_config.open_session(args)
    assert seen == [True, False, False, False]


def test_connect_timeout_from_flag_env_or_default(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("ZENOH_CONNECT_TIMEOUT_S", raising=False)
    assert zenoh_config.connect_timeout_s() == zenoh_config.CONNECT_TIMEOUT_S
    monkeypatch.setenv("ZENOH_CONNECT_TIMEOUT_S", "7.5")
    assert zenoh_config.connect_timeout_s() == 7.5
    assert zenoh_config.connect_timeout_s(2.0) == 2.0
    monkeypatch.setenv("ZENOH_CONNECT_TIMEOUT_S", "soon")
    with pytest.raises(RuntimeFailure, match=r"ZENOH_CONNECT_TIMEOUT_S = 'soon'; expected seconds"):
        zenoh_config.connect_timeout_s()


def test_shared_memory_is_off_even_under_a_users_config_file(
    tmp_path: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    # zenoh's default moves puts over 3 KB into shared memory, mapped on first receipt
    assert zenoh.Config().get_json("transport/shared_memory/enabled") == "true"
    assert (
        zenoh_config.session_config("client").get_json("transport/shared_memory/enabled") == "false"
    )
    config = tmp_path / "zenoh.json5"
    config.write_text("{transport: {shared_memory: {enabled: true}}}")
    monkeypatch.setenv("ZENOH_CONFIG", str(config))
    conf = zenoh_config.session_config("peer")
    assert conf.get_json("transport/shared_memory/enabled") == "false"


def test_a_members_zid_is_fixed_by_its_name_and_valid_for_zenoh() -> None:
    zid = zenoh_config.member_zid("agent-3")
    assert zid == zenoh_config.member_zid("agent-3") != zenoh_config.member_zid("agent-4")
    assert len(zid) == 32 and zid[0] != "0"  # zenoh refuses a leading 0
    session = zenoh.open(zenoh_config.session_config("peer", member="agent-3"))
    try:
        assert str(session.info.zid()) == zid
    finally:
        session.close()


def test_only_the_team_blocks_the_rest_drops() -> None:
    conf = zenoh_config.session_config("router", members=["netem", "agent-1"])
    observers, team = json.loads(conf.get_json("qos/network"))  # the last matching rule wins
    assert observers["overwrite"]["congestion_control"] == "drop" and not observers.get("zids")
    assert team["overwrite"]["congestion_control"] == "block"
    assert sorted(team["zids"]) == sorted(zenoh_config.member_zid(n) for n in ("netem", "agent-1"))
    wait = conf.get_json("transport/link/tx/queue/congestion_control/drop/wait_before_drop")
    assert json.loads(wait) == zenoh_config.DROP_WAIT_US
    # without a team, zenoh's defaults: every put as its publisher sent it
    assert json.loads(zenoh_config.session_config("router").get_json("qos/network")) == []


def test_the_team_from_the_file_the_environment_names(
    tmp_path: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    members = tmp_path / "members.json"
    members.write_text('["router", "leader"]')
    monkeypatch.setenv(zenoh_config.MEMBERS_FILE_ENV, str(members))
    monkeypatch.setenv(zenoh_config.MEMBER_ENV, "leader")
    conf = zenoh_config.session_config("client")
    assert json.loads(conf.get_json("id")) == zenoh_config.member_zid("leader")
    assert len(json.loads(conf.get_json("qos/network"))[1]["zids"]) == 2
    members.write_text('{"router": 1}')
    with pytest.raises(
        RuntimeFailure, match=r"FORMATION_MEMBERS_FILE = '.*members.json': expected"
    ):
        zenoh_config.session_config("client")
    members.unlink()
    with pytest.raises(RuntimeFailure, match=r"members.json': cannot read it"):
        zenoh_config.session_config("client")


def test_the_team_by_name_in_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(zenoh_config.MEMBERS_ENV, "router, netem,agent-1")  # compose.yaml's form
    zids = json.loads(zenoh_config.session_config("client").get_json("qos/network"))[1]["zids"]
    assert sorted(zids) == sorted(
        zenoh_config.member_zid(n) for n in ("router", "netem", "agent-1")
    )
