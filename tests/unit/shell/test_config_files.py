"""The files a Zenoh config names are checked readable first, and the error says who and what to do.

A missing file and a folder are unreadable to root too; a file its user may not read is the
integration test's (tests/integration/test_unreadable_files.py, a service as another uid).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from formation.errors import RuntimeFailure, UnreadableFile
from shell import session_config
from shell.config_files import named_files
from testbed.deploy.security import client_session_config


def test_a_missing_zenoh_config_is_named_with_its_variable_and_the_user(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    missing = tmp_path / "zenoh.json5"
    monkeypatch.setenv("ZENOH_CONFIG", str(missing))
    with pytest.raises(
        UnreadableFile,
        match=rf"^{missing} \(ZENOH_CONFIG\) cannot be read by uid {os.geteuid()} \(.+\): "
        r"no such file; name an existing file \(`formation keys keys/` writes a key set\)$",
    ):
        session_config("client", "tcp/127.0.0.1:7447")


def test_a_folder_where_the_config_should_be_says_an_engine_may_have_made_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("ZENOH_CONFIG", str(tmp_path))
    with pytest.raises(UnreadableFile, match=r"is a directory; it is owned by uid \d+ .* mode 0"):
        session_config("client", "tcp/127.0.0.1:7447")


def test_a_certificate_the_config_names_is_checked_too(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    ca = tmp_path / "ca.pem"
    config = tmp_path / "agent-1.json5"
    config.write_text(
        json.dumps({"transport": {"link": {"tls": {"root_ca_certificate": str(ca)}}}})
    )
    monkeypatch.setenv("ZENOH_CONFIG", str(config))
    with pytest.raises(
        UnreadableFile, match=rf"^{ca} \(transport/link/tls/root_ca_certificate\) .*no such file"
    ):
        session_config("client", "tcp/127.0.0.1:7447")
    ca.write_text("not checked for sense, only for reading")
    conf = session_config("client", "tcp/127.0.0.1:7447")
    assert named_files(conf) == [("transport/link/tls/root_ca_certificate", str(ca))]


def test_the_router_s_passwords_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("ZENOH_CONFIG", raising=False)
    passwords = tmp_path / "passwords.txt"
    extra = {"transport/auth/usrpwd/dictionary_file": str(passwords)}
    with pytest.raises(UnreadableFile, match=r"\(transport/auth/usrpwd/dictionary_file\)"):
        session_config("router", None, "tcp/127.0.0.1:7447", extra)


def test_a_config_that_is_not_json5_is_named_without_a_traceback(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    config = tmp_path / "zenoh.json5"
    config.write_text("{ not json5")
    monkeypatch.setenv("ZENOH_CONFIG", str(config))
    with pytest.raises(RuntimeFailure, match=rf"^{config} \(ZENOH_CONFIG\): not a Zenoh"):
        session_config("client", "tcp/127.0.0.1:7447")


def test_a_tool_s_config_file_is_checked(tmp_path: Path) -> None:
    with pytest.raises(UnreadableFile, match=r"\(the user's config\) .*no such file"):
        client_session_config("tcp/127.0.0.1:7447", tmp_path / "operator.json5")


def test_the_message_is_built_from_the_values() -> None:
    err = UnreadableFile(
        "/run/secrets/zenoh.json5",
        "ZENOH_CONFIG",
        "permission denied",
        1000,
        "no name in /etc/passwd",
        (0, "root", 0o600),
    )
    assert str(err) == (
        "/run/secrets/zenoh.json5 (ZENOH_CONFIG) cannot be read by uid 1000 (no name in "
        "/etc/passwd): permission denied; it is owned by uid 0 (root) with mode 0600; run the "
        "service as the file's owner (for the compose deployment: `export FORMATION_UID=$(id -u) "
        "FORMATION_GID=$(id -g)` before `up`, as the README says) or let uid 1000 read it"
    )
