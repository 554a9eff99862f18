"""The launcher's observer waits for netem's last status before a run's summary is taken:
netem publishes it after its last decisions, so the summary has every decision."""

from __future__ import annotations

import socket
import time

import pytest
import zenoh

from formation import keys
from formation.messages import Status
from formation.scenario import Scenario
from shell.zenoh_config import session_config
from testbed.runtime.observer import Observer

pytestmark = pytest.mark.integration
HOST = "127.0.0.1"


def _status(run_id: str, state: str, seq: int) -> bytes:
    msg = Status(run_id=run_id, sender="netem", seq=seq, epoch=0, stamp_ns=time.time_ns(),
                 role="netem", state=state)  # type: ignore[arg-type]  # fmt: skip
    return msg.model_dump_json().encode()


def test_netem_done_waits_for_its_last_status_and_not_for_a_running_one(paper: Scenario) -> None:
    with socket.socket() as s:
        s.bind((HOST, 0))
        port = s.getsockname()[1]
    session = zenoh.open(session_config("peer", None, f"tcp/{HOST}:{port}"))
    try:
        observer = Observer(session, "obs", paper)
        key = keys.status("obs", "netem", 0)
        session.put(key, _status("obs", "running", 0))
        assert not observer.netem_done(timeout_s=0.3), "a running status is not the last"
        session.put(key, _status("obs", "done", 1))
        assert observer.netem_done(timeout_s=10.0)
        observer.close()
    finally:
        session.close()
