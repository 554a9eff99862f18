"""A service whose user cannot read its credentials or the router's files (issue 26): it exits
with one line naming the file, the user, the file's owner and mode and what to do, not a
Zenoh traceback; and a recorder that fails this way leaves the recording already there intact.

Honest as root too: there the service drops to an unused uid before it runs and the file is
root's 0600, as ``formation keys`` writes it (:mod:`testkit.other_user`).
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import subprocess
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from formation import keys
from recorder.reading.reader import iter_messages, open_recording
from recorder.recording.writer import RecordingWriter
from testbed.runtime.processes import free_port
from testkit.other_user import AS_ROOT, OTHER, command, hand_over, shut

pytestmark = pytest.mark.integration
RUN = "unreadable"
TIMEOUT_S = 60.0  # the check comes before any connection: seconds, even on a loaded machine


@pytest.fixture
def shared() -> Iterator[Path]:
    """A folder the other uid can enter (pytest's tmp_path is root's 0700 under root)."""
    path = Path(tempfile.mkdtemp(prefix="formation-unreadable-"))
    os.chmod(path, 0o755)
    yield path
    shutil.rmtree(path)


def run_service(module: str, *args: str, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    """The service as :data:`OTHER`; subprocess.run kills it by PID if it overstays."""
    return subprocess.run(
        command(module, *args),
        env={**os.environ, **env},
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        stdin=subprocess.DEVNULL,
    )


def expected(name: str, path: Path, named_by: str) -> str:
    owner, mode = os.geteuid(), "0600" if AS_ROOT else "0000"
    return (
        rf"^{name}: error: {re.escape(str(path))} \({re.escape(named_by)}\) cannot be read by "
        rf"uid {OTHER} \([^)]+\): permission denied; it is owned by uid {owner} \([^)]+\) with "
        rf"mode {mode}; run the service as the file's owner \(for the compose deployment: "
        r"`export FORMATION_UID=\$\(id -u\) FORMATION_GID=\$\(id -g\)` before `up`, as the "
        rf"README says\) or let uid {OTHER} read it$"
    )


def secret(folder: Path, name: str = "zenoh.json5") -> Path:
    path = folder / name
    path.write_text('{ transport: { auth: { usrpwd: { user: "agent-1", password: "x" } } } }\n')
    shut(path)
    return path


def recording(path: Path) -> None:
    """A small finished recording, as a run before this one left it."""
    writer = RecordingWriter(path)
    for k in range(20):
        writer.write(keys.agent_state(RUN, 1), f'{{"epoch": {k}}}'.encode(), 1000 + k)
    writer.close()


def messages(path: Path) -> int:
    with open_recording(path) as (reader, _summary):
        return sum(1 for _ in iter_messages(path, reader))


@pytest.mark.parametrize("service", ["agent", "leader", "netem"])
def test_a_service_that_cannot_read_its_credentials_says_which_file_who_and_what_to_do(
    shared: Path, paper_path: Path, service: str
) -> None:
    conf = secret(shared)
    scenario = shared / "paper.toml"  # the checkout may be in a folder only root may enter
    shutil.copy(paper_path, scenario)
    hand_over(scenario)
    args = ["--scenario", str(scenario), "--run-id", RUN, "--mode", "client"]
    args += ["--connect", f"tcp/127.0.0.1:{free_port()}", "--connect-timeout", "1"]
    done = run_service(
        service,
        *args,
        *(["--id", "1"] if service == "agent" else []),
        env={"ZENOH_CONFIG": str(conf)},
    )
    assert done.returncode == 1, done.stderr
    assert "Traceback" not in done.stderr
    assert re.search(expected(service, conf, "ZENOH_CONFIG"), done.stderr, re.M), done.stderr


def test_the_router_that_cannot_read_its_passwords_file_says_so(shared: Path) -> None:
    passwords = secret(shared, "passwords.txt")
    done = run_service(
        "testbed.runtime.router",
        "--listen",
        f"tcp/127.0.0.1:{free_port()}",
        "--passwords",
        str(passwords),
        env={},
    )
    assert done.returncode == 1, done.stderr
    assert "Traceback" not in done.stderr
    named_by = "transport/auth/usrpwd/dictionary_file"
    assert re.search(expected("router", passwords, named_by), done.stderr, re.M), done.stderr


def test_a_recorder_that_cannot_read_its_credentials_leaves_the_recording_there(
    shared: Path,
) -> None:
    """Before, it opened run.mcap first and left it empty: a finished run's record lost."""
    conf = secret(shared)
    out = shared / "runs" / RUN
    out.mkdir(parents=True)
    mcap = out / "run.mcap"
    recording(mcap)
    for path in (shared / "runs", out, mcap):
        hand_over(path)  # the recorder's user could overwrite it: whether it does is the test
    before = hashlib.sha256(mcap.read_bytes()).hexdigest()
    done = run_service(
        "recorder",
        "--run-id",
        RUN,
        "--out",
        str(out),
        "--mode",
        "client",
        "--connect",
        f"tcp/127.0.0.1:{free_port()}",
        "--connect-timeout",
        "1",
        env={"ZENOH_CONFIG": str(conf)},
    )
    assert done.returncode == 1, done.stderr
    assert "Traceback" not in done.stderr
    assert re.search(expected("recorder", conf, "ZENOH_CONFIG"), done.stderr, re.M), done.stderr
    assert hashlib.sha256(mcap.read_bytes()).hexdigest() == before
    assert messages(mcap) == 20
    assert sorted(p.name for p in out.iterdir()) == ["run.mcap"]
